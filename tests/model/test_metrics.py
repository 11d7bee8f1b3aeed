"""PSNR, SSIM and depth metrics against hand-computed values."""

from __future__ import annotations

import math

import pytest
import torch

from model.metrics import depth_metrics, gaussian_window, psnr, ssim


def test_psnr_known_value() -> None:
    gt = torch.zeros(3, 8, 8)
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0)  # mse 0.01 -> 20 dB
    assert psnr(gt, gt) == math.inf


def test_ssim_identical_is_one_and_constant_images_hand_value() -> None:
    x = torch.rand(3, 20, 24, generator=torch.Generator().manual_seed(0))
    assert ssim(x, x) == pytest.approx(1.0, abs=1e-12)
    a, b = 0.3, 0.6  # constant images: variance and covariance vanish
    c1, c2 = 0.01**2, 0.03**2
    expected = (2 * a * b + c1) / (a**2 + b**2 + c1) * (c2 / c2)
    got = ssim(torch.full((16, 16), a), torch.full((16, 16), b))
    assert got == pytest.approx(expected, rel=1e-9)


def test_ssim_single_window_hand_computation() -> None:
    gen = torch.Generator().manual_seed(1)
    x, y = torch.rand(11, 11, generator=gen).double(), torch.rand(11, 11, generator=gen).double()
    w = gaussian_window()
    mx, my = (w * x).sum(), (w * y).sum()
    vx, vy = (w * (x - mx) ** 2).sum(), (w * (y - my) ** 2).sum()
    cxy = (w * (x - mx) * (y - my)).sum()
    c1, c2 = 0.01**2, 0.03**2
    ref = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
    assert ssim(x, y) == pytest.approx(ref.item(), rel=1e-9)
    assert ssim(x, y) < 0.5  # independent noise is dissimilar


def test_depth_metrics_hand_case() -> None:
    gt = torch.tensor([[1.0, 2.0], [4.0, 0.0]])  # last pixel invalid (no ground truth)
    pred = torch.tensor([[1.1, 2.0], [6.0, 9.0]])
    m = depth_metrics(pred, gt)
    assert m["abs_rel"] == pytest.approx((0.1 + 0.0 + 0.5) / 3)
    assert m["rmse"] == pytest.approx(math.sqrt((0.01 + 0 + 4.0) / 3))
    assert m["delta1"] == pytest.approx(2 / 3)
    valid = torch.tensor([[True, True], [False, True]])
    assert depth_metrics(pred, gt, valid)["abs_rel"] == pytest.approx(0.05)
    with pytest.raises(ValueError, match="no valid"):
        depth_metrics(pred, torch.zeros(2, 2))


def test_ssim_many_matches_the_direct_2d_window_per_image() -> None:
    """Separable batched SSIM against the textbook 2D-window SSIM, image by image."""
    import torch.nn.functional as F

    from model.metrics import psnr_many, ssim_many

    gen = torch.Generator().manual_seed(0)
    x = torch.rand(4, 3, 20, 31, generator=gen, dtype=torch.float64)
    y = (x + 0.1 * torch.randn(4, 3, 20, 31, generator=gen, dtype=torch.float64)).clamp(0, 1)
    w = gaussian_window()[None, None]

    def direct(a: torch.Tensor, b: torch.Tensor) -> float:
        def blur(t: torch.Tensor) -> torch.Tensor:
            return F.conv2d(t[:, None], w)[:, 0]

        mx, my = blur(a), blur(b)
        vx, vy, c = blur(a * a) - mx**2, blur(b * b) - my**2, blur(a * b) - mx * my
        s = ((2 * mx * my + 1e-4) * (2 * c + 9e-4)) / ((mx**2 + my**2 + 1e-4) * (vx + vy + 9e-4))
        return float(s.mean())

    many = ssim_many(x, y)
    for i in range(4):
        assert float(many[i]) == pytest.approx(direct(x[i], y[i]), abs=1e-12)
        assert float(psnr_many(x, y)[i]) == pytest.approx(psnr(x[i], y[i]), abs=1e-9)
