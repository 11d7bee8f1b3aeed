"""The science bench's baseline margins: the reprojection baseline beside the trivial ones."""

from __future__ import annotations

import pytest

from bench.science_report import aggregate, baseline_margins


def test_reprojection_margins_are_reported_and_never_the_bar() -> None:
    base = {"copy_source": {"psnr_mean": 15.0, "ssim_mean": 0.30},
            "mean_image": {"psnr_mean": 14.0, "ssim_mean": 0.40},
            "reprojection": {"psnr_mean": 16.5, "ssim_mean": 0.35}}
    out = baseline_margins(base, {1: (15.5, 0.33), 10: (14.5, 0.31)})
    assert out["psnr_reprojection"] == 16.5
    assert out["reprojection_margin_db"] == pytest.approx(1.5)
    assert out["reprojection_ssim_margin"] == pytest.approx(0.05)
    assert out["model_margin_reprojection_db_k1"] == pytest.approx(-1.0)
    assert out["model_margin_reprojection_db"] == pytest.approx(-2.0)
    assert out["strongest_baseline"] == "copy_source"  # the non-geometric bar
    assert out["model_margin_db_k1"] == pytest.approx(0.5)


def test_without_the_reprojection_baseline_no_margin_is_made_up() -> None:
    out = baseline_margins({"copy_source": {"psnr_mean": 15.0, "ssim_mean": 0.3}},
                           {1: (15.5, 0.33), 10: (14.5, 0.31)})
    assert not any("reprojection" in k for k in out)


def _scores(psnr: float, err: float | None) -> dict[str, object]:
    out: dict[str, object] = {"psnr_mean": psnr, "ssim_mean": 0.3, "baselines": {
        "copy_source": {"psnr_mean": 15.0, "ssim_mean": 0.3}}}
    if err is not None:
        out |= {"reproj_err": err, "reproj_targets": 4, "reproj_points_mean": 9.0,
                "reproj_err_baselines": {"ground_truth": 0.3, "copy_source": 0.9,
                                         "mean_latent": 1.0}}
    return out


def test_reprojection_consistency_per_mode_beside_its_floor_and_baselines() -> None:
    runs = [{"mode": m, "seed": s, "val_loss": 1.0, "train_minutes": 1.0,
             "eval_k1": _scores(16.0, e1), "eval_k10": _scores(16.0, e10)}
            for m, s, e1, e10 in (("full", 0, 0.5, 0.4), ("full", 1, 0.7, 0.6),
                                  ("no_lidar", 0, 0.8, 0.8), ("zero", 0, None, None))]
    out = aggregate(runs)
    assert out["reproj_err_full_k1"] == pytest.approx(0.6)
    assert out["reproj_err_full_k10_std"] == pytest.approx(0.1 * 2 ** 0.5)
    assert out["reproj_err_no_lidar_k10"] == 0.8
    assert "reproj_err_zero_k1" not in out  # runs without the geometry: no made-up value
    assert (out["reproj_err_ground_truth"], out["reproj_err_copy_source"],
            out["reproj_err_mean_latent"], out["reproj_targets"]) == (0.3, 0.9, 1.0, 4)
