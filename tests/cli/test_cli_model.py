"""Model CLI on a tiny cache whose latents are exact patch encodings of its images:
train, resume, sample (PNGs), eval (JSON + Parquet), bench sampler and bench loader."""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from PIL import Image
from safetensors.torch import load_file
from typer.testing import CliRunner

from cli.app import app
from model.checkpoint import read_meta
from model.encoders.patch import PatchEncoder
from model.train_log import read_log
from pipeline.analysis.figures import sampler_rows
from schemas.cache_layout import EncoderIdentity, GridSpec
from schemas.tables import CLIPS, write_table
from store.cache_store import open_root
from tests.model.cache_fixture import CU, build_cache, set_latent_norm

C = 588  # patch encoder channels at which decoding is exact
GRID = GridSpec(56, 84)  # 4 x 6 latent grid: divisible by the tiny preset's patch 2


def _fill(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
    """Smooth random images that brighten over frames; latents = their patch encodings."""
    rng = np.random.default_rng(len(rec) * 7 + len(cam))
    n, h, w, _ = arrays["images"].shape
    base = rng.integers(40, 200, (1, h // 14 + 1, w // 14 + 1, 3)).repeat(14, 1).repeat(14, 2)
    drift = np.arange(n)[:, None, None, None] * 2
    arrays["images"][:] = np.clip(base[:, :h, :w] + drift, 0, 255).astype(np.uint8)
    arrays["latents_l0"][:] = PatchEncoder(C).encode(arrays["images"])[0]
    arrays["K"][:] = [[60.0, 0, 41.5], [0, 60.0, 27.5], [0, 0, 1]]
    mask = rng.random(arrays["g"][:, :1].shape) < 0.6  # supported cells
    arrays["g"][:] = rng.random(arrays["g"].shape) * mask
    arrays["g"][:, :1] = mask
    arrays["h"][:] = rng.standard_normal(arrays["h"].shape) * mask


def _set_identities(out: Path, image: EncoderIdentity) -> None:
    """Write encoder identities into every cache group, as the encode stage does."""
    root = open_root(out / "cache.zarr")
    point = EncoderIdentity("fpfh", "1", "y", False, CU)
    for rec in ("r0", "r1"):
        for cam in ("front", "left"):
            root[f"{rec}/{cam}"].attrs.update({"image_encoder": asdict(image),
                                               "point_encoder": asdict(point)})


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cli_model")
    build_cache(out, grid=GRID, channels=(C, CU), fill=_fill)
    lat = np.concatenate([np.asarray(open_root(out / "cache.zarr")[f"r0/{c}/latents_l0"][:])
                          for c in ("front", "left")]).astype(np.float64)
    set_latent_norm(out, lat.mean((0, 2, 3)).tolist(), (lat.std((0, 2, 3)) + 1e-3).tolist())
    _set_identities(out, PatchEncoder(C).identity())
    clips = pq.read_table(out / "clips.parquet").to_pylist()
    for row in clips:  # every other clip is in the hard subset
        row["hard"] = row["clip_id"] % 2 == 0
    write_table(pa.Table.from_pylist(clips, schema=CLIPS), CLIPS, out / "clips.parquet")
    (out / "m3gd.yaml").write_text(f"output_dir: {out}\n"
                                   "train: {batch_size: 4, lr: 0.001}\n")
    return out


def _m3gd(out: Path, *args: str) -> str:
    """Run `m3gd -c <out>/m3gd.yaml ARGS`; return stdout (asserting exit code 0)."""
    result = CliRunner().invoke(app, ["-c", str(out / "m3gd.yaml"), *args])
    assert result.exit_code == 0, result.output
    return result.output


def _words(text: str) -> str:
    """`text` with every run of whitespace as one space (rich wraps long lines)."""
    return " ".join(text.split())


@pytest.fixture(scope="module")
def checkpoint(out_dir: Path) -> Path:
    _m3gd(out_dir, "train", "--steps", "3")
    return out_dir / "train" / "full"


def test_train_writes_checkpoint_and_reports(out_dir: Path, checkpoint: Path) -> None:
    state = read_meta(checkpoint)
    assert state["step"] == 3 and state["net"]["mode"] == "full"
    assert state["net"]["c"] == C and state["net"]["grid_hw"] == [4, 6]
    assert state["net"]["prediction"] == "x"  # the defaults, recorded in the checkpoint
    assert state["net"]["anchor"] == "none"
    assert sorted(p.name for p in checkpoint.iterdir()) == ["checkpoint.safetensors",
                                                            "metrics.jsonl", "run.json"]
    again = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--steps", "4"])
    assert again.exit_code == 1 and "--resume" in _words(again.output)  # never overwrites silently


def test_train_logs_scalars_that_plot_draws(out_dir: Path, checkpoint: Path) -> None:
    records = read_log(checkpoint / "metrics.jsonl")
    train = [r for r in records if r["kind"] == "train"]
    assert train[-1]["step"] == 3 and all(math.isfinite(train[-1][k]) for k in (
        "loss", "lr", "grad_norm", "steps_per_s", "clips_per_s"))
    (ev,) = [r for r in records if r["kind"] == "eval"]  # held-out scores at the end
    assert ev["step"] == 3 and len(ev["val_loss_t"]) == 5
    assert {"psnr_model", "psnr_copy_source", "psnr_mean_latent"} <= ev.keys()
    text = _m3gd(out_dir, "plot")
    assert "train_full.png" in text and (out_dir / "plots" / "train_full.png").stat().st_size


def test_progress_prints_plain_lines_with_rate_and_eta(out_dir: Path, tmp_path: Path) -> None:
    text = _m3gd(out_dir, "train", "--steps", "2", "--out", str(tmp_path / "p"), "--device",
                 "cpu")
    assert "training on cpu (fp32), 1 rank(s)" in _words(text)
    lines = [ln for ln in text.splitlines() if ln.startswith("step ")]
    assert len(lines) == 2 and all("steps/s" in ln and "ETA" in ln for ln in lines)
    # the end-of-run held-out scoring: announced before it starts, its result printed
    words = _words(text)
    assert "scoring step 2 on the first 8 eval clips" in words
    assert "held-out at step 2: validation loss" in words and "PSNR on" in words


def test_device_refused_in_one_line_when_absent(out_dir: Path, tmp_path: Path) -> None:
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    res = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--steps", "1",
                                   "--device", "cuda", "--out", str(tmp_path / "c")])
    assert res.exit_code == 2 and "sees no CUDA GPU" in _words(res.output)


def test_resume_continues_from_saved_step_exactly(out_dir: Path, tmp_path: Path) -> None:
    straight, split = tmp_path / "straight", tmp_path / "split"
    _m3gd(out_dir, "train", "--mode", "geom_only", "--steps", "4", "--out", str(straight))
    _m3gd(out_dir, "train", "--mode", "geom_only", "--steps", "2", "--out", str(split))
    text = _words(_m3gd(out_dir, "train", "--steps", "4", "--out", str(split), "--resume"))
    assert "resumed" in text and "at step 2" in text
    assert "checkpoint:" in text and "step 4" in text
    assert read_meta(split)["step"] == 4
    a = load_file(str(straight / "checkpoint.safetensors"))
    b = load_file(str(split / "checkpoint.safetensors"))
    assert a.keys() == b.keys()
    assert all(bool((a[k] == b[k]).all()) for k in a if k.startswith("model."))


def test_train_v_prediction_is_selectable_and_recorded(out_dir: Path, tmp_path: Path) -> None:
    _m3gd(out_dir, "train", "--steps", "1", "--prediction", "v", "--out", str(tmp_path / "v"))
    net = read_meta(tmp_path / "v")["net"]
    assert net["prediction"] == "v" and net["anchor"] == "none"
    bad = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--steps", "1",
                                   "--prediction", "v", "--anchor", "nearest_source",
                                   "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 1 and "needs prediction 'x'" in _words(bad.output)
    assert "Traceback" not in bad.output


def test_the_loss_space_and_the_reprojection_anchor_are_selectable_and_recorded(
        out_dir: Path, tmp_path: Path) -> None:  # fmt: skip
    _m3gd(out_dir, "train", "--steps", "1", "--mode", "warp", "--loss-space", "x",
          "--anchor", "reprojection", "--out", str(tmp_path / "x"))
    meta = read_meta(tmp_path / "x")
    assert meta["train"]["loss_space"] == "x" and meta["net"]["anchor"] == "reprojection"
    bad = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--steps", "1",
                                   "--anchor", "reprojection", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 1 and "needs a warp packet mode" in _words(bad.output)


def test_training_modes_are_selectable_and_recorded(out_dir: Path, tmp_path: Path) -> None:
    base = tmp_path / "no_lidar"
    _m3gd(out_dir, "train", "--mode", "no_lidar", "--steps", "2", "--out", str(base))
    frozen = tmp_path / "freeze"
    _m3gd(out_dir, "train", "--mode", "learnable", "--steps", "1", "--training-mode", "freeze",
          "--init-from", str(base), "--loss-views", "all", "--no-lidar-dropout",
          "--out", str(frozen))
    meta = read_meta(frozen)
    assert meta["net"]["mode"] == "learnable"
    assert meta["train"]["training_mode"] == "freeze"
    assert meta["train"]["init_from"] == str(base)
    assert meta["train"]["loss_views"] == "all" and meta["train"]["p_lidar"] == 0.0
    a = load_file(str(base / "checkpoint.safetensors"))
    b = load_file(str(frozen / "checkpoint.safetensors"))
    backbone = [k for k in a if k.startswith("model.backbone.")]
    assert backbone and all(bool((a[k] == b[k]).all()) for k in backbone)
    bad = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--steps", "1",
                                   "--training-mode", "finetune", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 1 and "needs --init-from" in _words(bad.output)


def test_resume_refuses_another_mode(out_dir: Path, checkpoint: Path) -> None:
    result = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--resume",
                                      "--mode", "zero", "--out", str(checkpoint)])
    assert result.exit_code == 1 and "trained with --mode full" in _words(result.output)


def test_sample_writes_pngs_beside_ground_truth(out_dir: Path, checkpoint: Path,
                                                tmp_path: Path) -> None:
    text = _m3gd(out_dir, "sample", str(checkpoint), "--clips", "2", "--steps", "2",
                 "--out", str(tmp_path))
    dirs = sorted((tmp_path / "samples").iterdir())
    assert len(dirs) == 2
    for d in dirs:
        for k in (0, 1):  # eval clips have 2 targets
            pred = np.asarray(Image.open(d / f"target_{k}_pred.png"))
            gt = np.asarray(Image.open(d / f"target_{k}_gt.png"))
            assert pred.shape == gt.shape == (GRID.image_h, GRID.image_w, 3)
            assert not np.array_equal(pred, gt)
            mse = ((pred.astype(float) - gt) ** 2).mean()
            assert 0 < 10 * math.log10(255**2 / mse) < 40
    assert "PSNR" in text and "4 targets written" in _words(text)
    assert "mean training image" in _words(text) and "strongest baseline" in _words(text)


def test_eval_prints_json_and_writes_results(out_dir: Path, checkpoint: Path,
                                             tmp_path: Path) -> None:
    result = tmp_path / "ev.json"
    run = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "eval", str(checkpoint),
                                   "--clips", "4", "--steps", "2", "--result", str(result),
                                   "--json"])
    assert run.exit_code == 0, run.output
    summary = json.loads(run.stdout)  # progress lines go to stderr
    assert "score clips: 4/4 (100 %)" in run.stderr
    assert summary == json.loads(result.read_text())
    assert summary["clips"] == 4 and summary["targets"] == 8 and summary["train_step"] == 3
    assert 0 < summary["psnr_mean"] < 40 and -1 <= summary["ssim_mean"] <= 1
    assert summary["hard"]["targets"] + summary["not_hard"]["targets"] == 8
    rows = pq.read_table(result.with_suffix(".parquet")).to_pylist()
    assert len(rows) == 8
    assert math.isclose(sum(r["psnr"] for r in rows) / 8, summary["psnr_mean"])
    assert {"copy_source", "mean_latent", "mean_image"} <= set(summary["baselines"])
    assert summary["better_baseline"] != "recording_mean_oracle"
    assert math.isclose(sum(r["psnr_mean_image"] for r in rows) / 8,
                        summary["baselines"]["mean_image"]["psnr_mean"])
    table = _m3gd(out_dir, "eval", str(checkpoint), "--clips", "2", "--steps", "1",
                  "--result", str(tmp_path / "t.json"))
    assert "hard" in table and "PSNR" in table
    assert summary["temperature"] == 1.0  # the configuration's: the paper's sampler


def _eval_psnrs(out_dir: Path, checkpoint: Path, where: Path, *extra: str) -> list[float]:
    _m3gd(out_dir, "eval", str(checkpoint), "--clips", "2", "--steps", "2", "--result",
          str(where), *extra)
    assert json.loads(where.read_text())["temperature"] == (float(extra[1]) if extra else 1.0)
    return [r["psnr"] for r in pq.read_table(where.with_suffix(".parquet")).to_pylist()]


def test_eval_temperature_zero_is_deterministic_and_recorded(out_dir: Path, checkpoint: Path,
                                                             tmp_path: Path) -> None:
    paper = _eval_psnrs(out_dir, checkpoint, tmp_path / "p.json")
    cold = _eval_psnrs(out_dir, checkpoint, tmp_path / "c.json", "--temperature", "0")
    (tmp_path / "seed.yaml").write_text(f"output_dir: {out_dir}\ntrain: {{seed: 7}}\n")
    run = CliRunner().invoke(app, ["-c", str(tmp_path / "seed.yaml"), "eval", str(checkpoint),
                                   "--clips", "2", "--steps", "2", "--temperature", "0",
                                   "--result", str(tmp_path / "c7.json")])
    assert run.exit_code == 0, run.output
    other_noise = pq.read_table(tmp_path / "c7.parquet").to_pylist()
    assert [r["psnr"] for r in other_noise] == cold  # no noise left to draw
    assert cold != paper
    refused = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "eval",
                                       str(checkpoint), "--temperature", "-1"])
    assert refused.exit_code == 2 and "--temperature" in refused.output
    infinite = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "eval",
                                        str(checkpoint), "--temperature", "inf"])
    assert infinite.exit_code == 1
    assert "temperature must be finite and >= 0, got inf" in _words(infinite.output)


def test_sample_refuses_encoder_without_decoder(out_dir: Path, checkpoint: Path,
                                                tmp_path: Path) -> None:
    other = tmp_path / "da3"
    shutil.copytree(out_dir, other, ignore=shutil.ignore_patterns("train", "samples"))
    (other / "m3gd.yaml").write_text(f"output_dir: {other}\n")
    _set_identities(other, EncoderIdentity("da3", "1", "w", True, C))
    result = CliRunner().invoke(app, ["-c", str(other / "m3gd.yaml"), "sample", str(checkpoint)])
    assert result.exit_code == 1 and "has no decoder" in _words(result.output)


def test_bench_sampler_quick_json_then_speed_accuracy_plot(tmp_path: Path) -> None:
    cfg = tmp_path / "m3gd.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "bench", "sampler", "--quick", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert set(out["latency"]) == {"1", "2"} and set(out["latency"]["1"]) == {"2"}
    assert out["latency"]["2"]["2"]["latency_s"] > 0
    saved = json.loads((tmp_path / "out" / "bench" / "sampler.json").read_text())
    rows = sampler_rows(saved)
    assert sorted((r["K"], r["M"]) for r in rows) == [(1.0, 2.0), (2.0, 2.0)]
    assert rows[0]["latency_s"] == out["latency"][str(int(rows[0]["K"]))]["2"]["latency_s"]
    plotted = CliRunner().invoke(app, ["-c", str(cfg), "plot"])
    assert plotted.exit_code == 0, plotted.output
    assert (tmp_path / "out" / "plots" / "speed_accuracy.png").stat().st_size > 1000


def test_bench_loader_on_tiny_cache(out_dir: Path) -> None:
    text = _m3gd(out_dir, "bench", "loader", "--cache", str(out_dir), "--workers", "0",
                 "--min-clips", "8", "--model-steps", "2", "--json")
    out = json.loads(text)
    assert out["loader_over_model"] > 0
    assert out["loader_over_model"] == pytest.approx(
        out["loader_clips_per_s_0_workers"] / out["model_clips_per_s"])


@pytest.mark.slow
def test_bench_loader_builds_its_cache_with_workers() -> None:
    result = CliRunner().invoke(app, ["bench", "loader", "--json", "--min-clips", "16"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["loader_over_model"] > 0 and out["loader_clips_per_s_2_workers"] > 0
    assert out["cache_build_s"] > 0


def test_model_commands_are_registered() -> None:
    for path in (["train"], ["sample"], ["eval"], ["bench", "sampler"], ["bench", "loader"]):
        result = CliRunner().invoke(app, [*path, "--help"])
        assert result.exit_code == 0 and "Usage" in result.output, path


def test_train_refuses_unknown_preset(out_dir: Path, tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--preset",
                                      "huge", "--out", str(tmp_path / "ck")])
    assert result.exit_code == 1 and "unknown preset 'huge'" in _words(result.output)


def test_the_hint_below_a_baseline_names_the_temperature_only_for_draws() -> None:
    from cli.model_lines import recipe_hint as _recipe_hint

    below = {"margin_db": -0.8, "better_baseline": "copy_source"}
    draw = _recipe_hint(below, {"train_step": 4, "steps": 10, "temperature": 1.0})
    assert draw is not None and "after 4 training steps" in draw
    assert "at temperature 1 a 10-step sample is a draw" in draw and "--temperature 0" in draw
    for settings in ({"train_step": 4, "steps": 10, "temperature": 0.0},
                     {"train_step": 4, "steps": 1, "temperature": 1.0}):
        hint = _recipe_hint(below, settings)
        assert hint is not None and "--temperature" not in hint
    assert _recipe_hint({"margin_db": 0.3, "better_baseline": "copy_source"},
                        {"train_step": 4, "steps": 10, "temperature": 1.0}) is None


def test_bench_science_refuses_an_absent_gpu_in_one_line(out_dir: Path, tmp_path: Path) -> None:
    """`m3gd bench science --device cuda` on a machine without one: one line, before any
    cache is built or run trained."""
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    res = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "bench", "science",
                                   "--quick", "--device", "cuda",
                                   "--workdir", str(tmp_path / "w")])
    assert res.exit_code == 2 and "sees no CUDA GPU" in _words(res.output)
    assert not (tmp_path / "w").exists()


def test_eval_without_an_eval_clip_says_why_and_what_to_set(out_dir: Path, checkpoint: Path,
                                                            tmp_path: Path) -> None:
    """One recording split by recording (every clip train): eval names the split and the
    setting that gives it eval clips, in one line."""
    out = tmp_path / "one"
    shutil.copytree(out_dir, out, ignore=shutil.ignore_patterns("train", "m3gd.yaml"))
    clips = [r for r in pq.read_table(out / "clips.parquet").to_pylist() if r["recording"] == "r0"]
    write_table(pa.Table.from_pylist(clips, schema=CLIPS), CLIPS, out / "clips.parquet")
    (out / "m3gd.yaml").write_text(f"output_dir: {out}\n")
    result = CliRunner().invoke(app, ["-c", str(out / "m3gd.yaml"), "eval", str(checkpoint),
                                      "--result", str(tmp_path / "eval.json")])
    assert result.exit_code == 1
    text = _words(result.output)
    assert "no 'eval' clip: the clips are split by recording" in text
    assert "set clips.split: segment" in text
