"""The science bench's baseline margins: the reprojection baseline beside the trivial ones."""

from __future__ import annotations

import pytest

from bench.science_report import baseline_margins


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
