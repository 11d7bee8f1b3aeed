"""The paper suite's tables: rows over seeds, paired differences, headline effects and the
baselines on the same targets."""

from __future__ import annotations

import math
from typing import Any

import pytest

from bench.science_paper_tables import aggregate_paper

BASE = {"copy_source": (15.0, 0.2), "mean_latent": (14.0, 0.3), "mean_image": (16.0, 0.25)}


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


def test_aggregate_rows_carry_the_validation_loss() -> None:
    runs = [{**_run("full", s, 18.0, 18.0, 18.0), "val_loss": v}
            for s, v in ((0, 1.0), (1, 2.0))]
    row = aggregate_paper(runs)["rows"]["full"]
    assert row["val_loss"] == pytest.approx(1.5)
    assert row["val_loss_std"] == pytest.approx(math.sqrt(0.5))


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
