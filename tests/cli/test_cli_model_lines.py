"""What `m3gd eval` and `m3gd train` say of the scores: the strongest of every baseline, the
held-out scoring in one line."""

from __future__ import annotations

from model.evaluate import TargetResult
from model.scoring import _means


def _result(psnr: float, ssim: float, base: dict[str, tuple[float, float]]) -> TargetResult:
    return TargetResult(0, 1, None, None, psnr, ssim, base)


def test_the_margin_line_names_the_strongest_of_every_baseline() -> None:
    from cli.model_lines import margin_line as _margin_line

    base = {"copy_source": (15.0, 0.40), "reprojection": (16.5, 0.35)}
    line = _margin_line(_means([_result(16.0, 0.38, base)]))
    assert "margin over the strongest baseline (LiDAR reprojection) -0.50 dB" in line
    assert "SSIM -0.020 against copy-nearest-source" in line
    assert "TRAILS the strongest baseline in PSNR and SSIM" in line


def test_a_held_out_scoring_reads_as_one_line() -> None:
    from cli.model_lines import held_out_line

    line = held_out_line({"val_loss_t": [0.5], "val_loss_mean": 0.5, "psnr_model": 12.0,
                          "eval_clips": 4, "psnr_copy_source": 11.5, "psnr_reprojection": 13.0})
    assert line == ("validation loss 0.5000; PSNR on 4 clips: model 12.00 dB "
                    "(copy-nearest-source 11.50, LiDAR reprojection 13.00)")
    assert "no PSNR" in held_out_line({"val_loss_t": [0.5], "val_loss_mean": 0.5})
