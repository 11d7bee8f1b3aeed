"""The paper suite: subsets by median, paired tables and headline effects, the M-target clip
index; and, marked slow, the --quick suite end to end through the real pipeline."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from bench.science import ScienceData
from bench.science_paper import (
    CPU_PAPER,
    PAPER_HEADLINE,
    QUICK_PAPER,
    aggregate_paper,
    m_target_index,
    run_paper,
    subsets,
    with_rows,
)
from bench.science_paper_rows import VARIANTS, WARP_TABLE, Variant
from model.dataset import load_clips
from model.evaluate import TargetResult
from tests.model.cache_fixture import build_cache

BASE = {"copy_source": (15.0, 0.2), "mean_latent": (14.0, 0.3), "mean_image": (16.0, 0.25)}


def _target(clip: int, view: int, psnr: float) -> TargetResult:
    return TargetResult(clip, view, None, None, psnr, 0.3, dict(BASE))


def test_subsets_cut_strictly_above_the_median() -> None:
    clips = [{"clip_id": i, "max_baseline_m": b} for i, b in enumerate((1.0, 2.0, 3.0))]
    results = [_target(0, 1, 10.0), _target(1, 1, 20.0), _target(2, 1, 30.0)]
    dtau = {(0, 1): 0.03, (1, 1): 0.01, (2, 1): 0.02}
    out = subsets(results, clips, dtau)
    assert out["hard_cut_m"] == 2.0 and out["hard"]["targets"] == 1  # the median clip is out
    assert out["hard"]["psnr_mean"] == 30.0
    assert out["dtau_cut_s"] == 0.02 and out["large_dtau"]["psnr_mean"] == 10.0
    assert out["all"]["better_baseline"] == "mean_image"
    assert out["all"]["margin_db"] == pytest.approx(20.0 - 16.0)


def _run(variant: str, seed: int, k1: float, hard: float, dt: float) -> dict[str, Any]:
    def part(p: float) -> dict[str, Any]:
        return {"psnr_mean": p, "ssim_mean": 0.3, "margin_db": p - 16.0,
                "baselines": {n: {"psnr_mean": v[0], "ssim_mean": v[1]}
                              for n, v in BASE.items()}, "better_baseline": "mean_image"}

    score = {"all": part(k1), "hard": part(hard), "large_dtau": part(dt), "hard_cut_m": 1.5,
             "dtau_cut_s": 0.01}
    return {"variant": variant, "mode": variant, "seed": seed, "train_minutes": 1.0,
            "eval_k1": score, "eval_k10": score}


def test_aggregate_pairs_by_seed_and_names_the_headline_effects() -> None:
    runs = [_run("freeze_full", 0, 18.0, 19.0, 17.0), _run("freeze_full", 1, 18.4, 19.2, 17.0),
            _run("freeze_no_lidar", 0, 17.5, 18.0, 16.0),
            _run("freeze_no_lidar", 1, 18.3, 18.8, 16.5),
            _run("full", 0, 18.0, 18.0, 17.2), _run("full_no_dtau", 0, 18.0, 18.0, 17.0),
            _run("learnable", 0, 17.0, 17.0, 17.0)]
    out = aggregate_paper(runs)
    assert out["freeze_lidar_gain_db"] == pytest.approx(0.3)  # (0.5 + 0.1) / 2
    assert out["freeze_lidar_gain_db_std"] == pytest.approx(math.sqrt(0.08))
    assert out["freeze_lidar_gain_hard_db"] == pytest.approx(0.7)
    assert out["dtau_channel_effect_db"] == pytest.approx(0.2)  # on large |dtau| targets
    assert out["dtau_channel_effect_db_pairs"] == 1
    assert "dtau_channel_effect_offset_db" not in out  # no offset runs
    assert out["psnr_k1_freeze_full"] == pytest.approx(18.2)
    assert out["psnr_k1_freeze_full_std"] == pytest.approx(math.sqrt(0.08))
    assert out["paired_vs_learnable"]["full - learnable"]["psnr_k1"]["values"] == [1.0]
    pair = out["paired_training"]["freeze_full - freeze_no_lidar"]["psnr_k1"]
    assert pair["positive"] == 2 and "p" in pair
    assert out["psnr_mean_image"] == 16.0 and out["strongest_baseline"] == "mean_image"
    assert out["rows"]["full"]["margin_db_k1"] == pytest.approx(2.0)


def test_warp_rows_pair_with_no_lidar_full_and_each_baseline() -> None:
    runs = [_run("no_lidar", 0, 17.0, 17.0, 17.0), _run("no_lidar", 1, 17.2, 17.0, 17.0),
            _run("warp", 0, 18.5, 18.0, 18.0), _run("warp", 1, 19.1, 18.0, 18.0),
            _run("full", 0, 17.5, 17.0, 17.0), _run("full_warp", 0, 18.0, 18.0, 18.0)]
    out = aggregate_paper(runs)
    assert out["psnr_k1_warp"] == pytest.approx(18.8) and out["psnr_k10_warp"] == 18.8
    lidar = out["paired_vs_no_lidar"]["warp - no_lidar"]["psnr_k1"]
    assert lidar["values"] == pytest.approx([1.5, 1.9]) and lidar["positive"] == 2
    assert out["paired_warp"]["warp - full"]["psnr_k10"]["values"] == pytest.approx([1.0])
    assert out["paired_warp"]["full_warp - warp"]["psnr_k1"]["values"] == pytest.approx([-0.5])
    vs_best = out["paired_vs_baselines"]["warp - mean_image"]["psnr_k1"]  # same targets
    assert vs_best["values"] == pytest.approx([2.5, 3.1]) and "p" in vs_best
    assert out["psnr_k1_copy_source"] == out["psnr_k10_copy_source"] == 15.0
    one = out["paired_vs_no_lidar"]["full_warp - no_lidar"]["psnr_k1"]  # seed 0 only
    assert one["values"] == pytest.approx([1.0]) and one["std"] == 0.0


def test_with_rows_keeps_the_named_rows_and_what_they_start_from() -> None:
    warp = with_rows(CPU_PAPER, WARP_TABLE)
    assert [v.name for v in warp.variants] == ["full", "no_lidar", "warp", "full_warp",
                                               "warp_x", "no_lidar_x"]
    x = {v.name: v for v in warp.variants}["warp_x"]
    assert (x.mode, x.loss_space, x.train_over()["loss_space"]) == ("warp", "x", "x")
    anchored = {v.name: v for v in VARIANTS}["warp_anchor_x"]
    assert (anchored.mode, anchored.anchor, anchored.loss_space) == ("warp", "reprojection", "x")
    assert warp.ms == () and warp.preset == CPU_PAPER.preset
    frozen = with_rows(CPU_PAPER, ["freeze_full"])
    assert [v.name for v in frozen.variants] == ["no_lidar", "freeze_full"]
    with pytest.raises(ValueError, match="unknown rows"):
        with_rows(CPU_PAPER, ["warp", "wrap"])


def test_variant_lr_overrides_the_spec_only_when_set() -> None:
    assert "lr" not in Variant("full", "full").train_over()
    low = Variant("ft", "full", "finetune", "no_lidar", lr=1e-4).train_over()
    assert low["lr"] == 1e-4 and low["training_mode"] == "finetune"
    names = [v.name for v in VARIANTS]
    assert names.index("finetune_full_lr1e-4") > names.index("no_lidar")  # no_lidar first


def test_aggregate_rows_carry_the_validation_loss() -> None:
    runs = [{**_run("full", s, 18.0, 18.0, 18.0), "val_loss": v}
            for s, v in ((0, 1.0), (1, 2.0))]
    row = aggregate_paper(runs)["rows"]["full"]
    assert row["val_loss"] == pytest.approx(1.5)
    assert row["val_loss_std"] == pytest.approx(math.sqrt(0.5))


def test_m_target_index_draws_two_sources_and_m_targets(tmp_path: Path) -> None:
    out = tmp_path / "run"
    def valid(_rec: str, _cam: str, arrays: dict[str, Any]) -> None:
        arrays["valid"][:] = True

    build_cache(out, ("r0", "r1"), ("front",), fill=valid)
    data = ScienceData(gap_min=1, gap_max=2, eval_clips_per_recording=3)
    where = m_target_index(out, 3, tmp_path / "m", data)
    assert (where / "cache.zarr").resolve() == (out / "cache.zarr").resolve()
    assert load_clips(where, "train") == load_clips(out, "train")
    ev = load_clips(where, "eval")
    assert ev and all(len(c["frames"]) == 5 and sum(c["is_target"]) == 3 for c in ev)
    assert {c["recording"] for c in ev} == {"r1"}


@pytest.mark.slow
def test_quick_paper_suite_end_to_end(tmp_path: Path) -> None:
    from dags.graph import STAGES

    out = run_paper(QUICK_PAPER, tmp_path, STAGES)
    for key in PAPER_HEADLINE:
        assert key in out, key
    assert set(out["psnr_by_m"]) == {"2", "3"}
    assert all(math.isfinite(out[f"psnr_k1_{m}"]) for m in ("full", "learnable", "no_lidar"))
    assert (tmp_path / "paper.json").exists()
    again = run_paper(QUICK_PAPER, tmp_path, STAGES, train_missing=False)
    assert again["psnr_k1_full"] == out["psnr_k1_full"]


def test_rows_carry_the_reprojection_consistency_where_scored() -> None:
    runs = [_run("warp", 0, 18.0, 18.0, 18.0), _run("warp", 1, 18.0, 18.0, 18.0),
            _run("no_lidar", 0, 17.0, 17.0, 17.0)]
    for r, err in zip(runs[:2], (0.4, 0.6), strict=True):
        r["eval_k1"] = {**r["eval_k1"], "all": {
            **r["eval_k1"]["all"], "reproj_err": err, "reproj_targets": 5,
            "reproj_err_baselines": {"ground_truth": 0.2, "copy_source": 0.9}}}
    out = aggregate_paper(runs)
    assert out["reproj_err_k1_warp"] == pytest.approx(0.5)
    assert out["rows"]["warp"]["reproj_err_k1_std"] == pytest.approx(0.1 * math.sqrt(2))
    assert "reproj_err_k10_warp" not in out and "reproj_err_k1_no_lidar" not in out
    assert out["reproj_err_ground_truth"] == 0.2 and out["reproj_err_copy_source"] == 0.9
