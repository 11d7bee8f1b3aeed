"""The sampler temperature through the CLI: `m3gd train --val-recordings` records it in the
checkpoint; `m3gd sample` / `m3gd eval` use it by default, --temperature overrides it, a
checkpoint without one samples at 1 (the paper's) with a note."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cli.app import app
from model.checkpoint import read_meta
from model.encoders.patch import PatchEncoder
from model.temperature import SAMPLER_KEY, SAMPLER_VERSION, TEMPERATURES, record_sampler
from schemas.cache_layout import GridSpec
from schemas.tables import CLIPS, write_table
from store.cache_store import open_root
from tests.model.cache_fixture import CU, build_cache, set_latent_norm

C = 588  # patch encoder channels at which decoding is exact
RECORDINGS = ("r0", "r1", "r2")


def _fill(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
    """Smooth random images; latents = their patch encodings; 60 % LiDAR support."""
    rng = np.random.default_rng(len(rec) * 7 + int(rec[1:]))
    n, h, w, _ = arrays["images"].shape
    base = rng.integers(40, 200, (1, h // 14 + 1, w // 14 + 1, 3)).repeat(14, 1).repeat(14, 2)
    arrays["images"][:] = np.clip(base[:, :h, :w] + np.arange(n)[:, None, None, None], 0,
                                  255).astype(np.uint8)
    arrays["latents_l0"][:] = PatchEncoder(C).encode(arrays["images"])[0]
    arrays["K"][:] = [[60.0, 0, 41.5], [0, 60.0, 27.5], [0, 0, 1]]
    mask = rng.random(arrays["g"][:, :1].shape) < 0.6
    arrays["g"][:] = rng.random(arrays["g"].shape) * mask
    arrays["g"][:, :1] = mask


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """r0 and r1 training recordings, r2 the eval one; encoder identities as encode's."""
    out = tmp_path_factory.mktemp("cli_temperature")
    build_cache(out, RECORDINGS, ("front",), grid=GridSpec(56, 84), channels=(C, CU),
                fill=_fill)
    lat = np.concatenate([np.asarray(open_root(out / "cache.zarr")[f"{r}/front/latents_l0"][:])
                          for r in RECORDINGS]).astype(np.float64)
    set_latent_norm(out, lat.mean((0, 2, 3)).tolist(), (lat.std((0, 2, 3)) + 1e-3).tolist())
    root = open_root(out / "cache.zarr")
    ident = {"image_encoder": {**PatchEncoder(C).identity().__dict__},
             "point_encoder": {"name": "fpfh", "version": "1", "weights_hash": "y",
                               "pretrained": False, "channels": CU}}
    for rec in RECORDINGS:
        root[f"{rec}/front"].attrs.update(ident)
    clips = pq.read_table(out / "clips.parquet").to_pylist()
    for row in clips:
        row["split"] = "eval" if row["recording"] == "r2" else "train"
    write_table(pa.Table.from_pylist(clips, schema=CLIPS), CLIPS, out / "clips.parquet")
    (out / "m3gd.yaml").write_text(f"output_dir: {out}\ntrain: {{batch_size: 2, lr: 0.001}}\n"
                                   "sample: {steps: 2}\n")
    return out


def _m3gd(out: Path, *args: str) -> tuple[str, str]:
    """Run `m3gd -c <out>/m3gd.yaml ARGS`; (stdout, stderr), asserting exit code 0."""
    result = CliRunner().invoke(app, ["-c", str(out / "m3gd.yaml"), *args])
    assert result.exit_code == 0, result.output
    return result.stdout, result.stderr


@pytest.fixture(scope="module")
def untrained(out_dir: Path) -> Path:
    """A checkpoint of the cache's network at step 0 that records no temperature (as one
    of an older m3gd); made in code, faster than `m3gd train`."""
    from dataclasses import replace

    from model.compare import net_config_from_cache
    from model.dataset import ClipStream
    from model.train_step import TrainConfig, Trainer

    cfg = replace(net_config_from_cache(ClipStream(out_dir, "train", "full"), "full", "tiny"),
                  patch=1)
    Trainer(cfg, TrainConfig(lr=1e-3)).save(out_dir / "untrained")
    return out_dir / "untrained"


@pytest.mark.slow
def test_train_records_the_validation_choice(out_dir: Path, tmp_path: Path) -> None:
    text, _ = _m3gd(out_dir, "train", "--steps", "2", "--val-recordings", "1",
                    "--out", str(tmp_path / "chosen"))
    assert "sampler temperature" in text and "validation recordings" in text
    block = read_meta(tmp_path / "chosen")[SAMPLER_KEY]
    assert block["version"] == 1 and block["temperature"] in TEMPERATURES
    assert block["steps"] == 2 and len(block["recordings"]) == 1
    assert block["recordings"][0] in ("r0", "r1")
    assert block["recordings"][0] in text
    assert set(block["val_psnr"]) == {f"{t:g}" for t in TEMPERATURES}
    best = max(block["val_psnr"].values())
    assert block["val_psnr"][f"{block['temperature']:g}"] == best
    again, _ = _m3gd(out_dir, "eval", str(tmp_path / "chosen"), "--clips", "1", "--json")
    assert json.loads(again)["temperature"] == block["temperature"]


def _with_temperature(src: Path, dst: Path, t: float) -> Path:
    """A copy of checkpoint `src` recording temperature `t` as a --val-recordings run does."""
    import shutil

    shutil.copytree(src, dst)
    record_sampler(dst, {"version": SAMPLER_VERSION, "temperature": t, "steps": 2,
                         "guidance": 1.5, "val_psnr": {f"{t:g}": 20.0}, "recordings": ["r1"],
                         "clips": 2})
    return dst


def test_eval_uses_the_recorded_temperature_and_records_it(out_dir: Path, untrained: Path,
                                                           tmp_path: Path) -> None:
    ck = _with_temperature(untrained, tmp_path / "ck", 0.25)
    text, err = _m3gd(out_dir, "eval", str(ck), "--clips", "2", "--json")
    summary = json.loads(text)
    assert summary["temperature"] == 0.25
    assert "the checkpoint's" in summary["temperature_from"]
    assert "temperature_note" not in summary
    assert "temperature 0.25: the checkpoint's" in err
    saved = json.loads((ck / "eval.json").read_text())
    assert saved["temperature"] == 0.25 and saved["temperature_from"] == summary["temperature_from"]


def test_an_explicit_temperature_overrides_the_checkpoint(out_dir: Path, untrained: Path,
                                                          tmp_path: Path) -> None:
    ck = _with_temperature(untrained, tmp_path / "ck", 0.25)
    text, _ = _m3gd(out_dir, "eval", str(ck), "--clips", "2", "--json", "--temperature", "1")
    summary = json.loads(text)
    assert summary["temperature"] == 1.0 and summary["temperature_from"] == "--temperature"
    text, _ = _m3gd(out_dir, "sample", str(ck), "--clips", "1", "--temperature", "0",
                    "--out", str(tmp_path / "s"))
    assert "T=0.0" in text


def test_sample_uses_the_recorded_temperature(out_dir: Path, untrained: Path,
                                              tmp_path: Path) -> None:
    ck = _with_temperature(untrained, tmp_path / "ck", 0.5)
    text, err = _m3gd(out_dir, "sample", str(ck), "--clips", "1", "--out", str(tmp_path / "s"))
    assert "T=0.5" in text and "temperature 0.5: the checkpoint's" in err


def test_a_checkpoint_without_a_temperature_samples_at_1_with_a_note(out_dir: Path,
                                                                      untrained: Path) -> None:
    assert SAMPLER_KEY not in read_meta(untrained)
    text, err = _m3gd(out_dir, "eval", str(untrained), "--clips", "1", "--json", "--result",
                      str(out_dir / "old_eval.json"))
    summary = json.loads(text)
    assert summary["temperature"] == 1.0 and "records none" in summary["temperature_from"]
    assert "note: the checkpoint records no sampler temperature" in err
    assert "temperature_note" in summary


def test_a_configured_temperature_beats_the_checkpoint(out_dir: Path, untrained: Path,
                                                       tmp_path: Path) -> None:
    ck = _with_temperature(untrained, tmp_path / "ck", 0.25)
    cfg = tmp_path / "m3gd.yaml"
    cfg.write_text((out_dir / "m3gd.yaml").read_text().replace("{steps: 2}",
                                                               "{steps: 2, temperature: 0.5}"))
    result = CliRunner().invoke(app, ["-c", str(cfg), "eval", str(ck), "--clips", "1",
                                      "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["temperature"] == 0.5
    assert summary["temperature_from"] == "config sample.temperature"


def test_too_many_validation_recordings_is_one_line(out_dir: Path, tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["-c", str(out_dir / "m3gd.yaml"), "train", "--steps",
                                      "1", "--val-recordings", "2", "--out",
                                      str(tmp_path / "x")])
    assert result.exit_code != 0
    assert "2 recording(s); hold out at least 1 and leave at least 1" in result.output
