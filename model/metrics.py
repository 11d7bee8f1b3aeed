"""Image and depth metrics: PSNR, SSIM (Wang et al. 2004), AbsRel, RMSE, delta < 1.25.

SSIM uses the standard constants: 11x11 Gaussian window with sigma 1.5 (normalized),
K1 = 0.01, K2 = 0.03, C_i = (K_i L)^2 with L the data range, statistics over the 'valid'
region (no padding), per channel, then averaged over pixels and channels.
All metrics compute in float64 and return Python floats per image.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from schemas.errors import DataError


def psnr(pred: Tensor, gt: Tensor, data_range: float = 1.0) -> float:
    """PSNR in dB of two images (C, H, W) or (H, W) in [0, data_range]; inf if identical."""
    mse = ((pred.double() - gt.double()) ** 2).mean().item()
    return math.inf if mse == 0 else 10.0 * math.log10(data_range**2 / mse)


def psnr_many(pred: Tensor, gt: Tensor, data_range: float = 1.0) -> Tensor:
    """PSNR in dB per image of two stacks (N, C, H, W) -> (N,) float64; inf where identical."""
    mse = ((pred.double() - gt.double()) ** 2).flatten(1).mean(1)
    return 10.0 * torch.log10(data_range**2 / mse)


def gaussian_window_1d(size: int = 11, sigma: float = 1.5) -> Tensor:
    """Normalized 1D Gaussian window (size,), float64."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def gaussian_window(size: int = 11, sigma: float = 1.5) -> Tensor:
    """Normalized 2D Gaussian window (size, size), float64: the outer product of the 1D one."""
    g = gaussian_window_1d(size, sigma)
    return g[:, None] * g[None, :]


def ssim(pred: Tensor, gt: Tensor, data_range: float = 1.0, size: int = 11,
         sigma: float = 1.5, k1: float = 0.01, k2: float = 0.03) -> float:
    """Mean SSIM of two images (C, H, W) or (H, W); both sides must be >= `size`."""
    x = pred[None] if pred.dim() == 2 else pred  # (C, H, W)
    y = gt[None] if gt.dim() == 2 else gt
    return float(ssim_many(x[None], y[None], data_range, size, sigma, k1, k2)[0])


def blur_valid(x: Tensor, taps: Tensor, dim: int) -> Tensor:
    """'Valid' correlation of x with the 1-D window `taps` along `dim`: len(taps) shifted,
    weighted adds. Memory is the output's size (a float64 conv2d on the CPU unfolds its
    whole input, 11x the moments: gigabytes for a batch of images)."""
    k = taps.shape[0]
    n = x.shape[dim] - k + 1
    out = x.narrow(dim, 0, n) * taps[0]
    for i in range(1, k):
        out.add_(x.narrow(dim, i, n), alpha=float(taps[i]))
    return out


def ssim_many(pred: Tensor, gt: Tensor, data_range: float = 1.0, size: int = 11,
              sigma: float = 1.5, k1: float = 0.01, k2: float = 0.03) -> Tensor:
    """Mean SSIM per image of two stacks (N, C, H, W) -> (N,) float64.

    The Gaussian window is separable (g g^T), so the five local moments are blurred by one
    row and one column pass over all of them stacked (22 instead of 121 taps per pixel).
    """
    x, y = pred.double(), gt.double()
    if x.shape != y.shape:
        raise DataError(f"ssim: shapes differ {tuple(x.shape)} vs {tuple(y.shape)}")
    if min(x.shape[-2:]) < size:
        raise DataError(f"ssim: image {tuple(x.shape[-2:])} smaller than the {size} window")
    n = x.shape[0]
    x, y = x.flatten(0, 1), y.flatten(0, 1)  # (N C, H, W)
    g = gaussian_window_1d(size, sigma)
    moments = torch.stack([x, y, x * x, y * y, x * y])  # (5, N C, H, W)
    blurred = blur_valid(blur_valid(moments, g, -1), g, -2)  # (5, N C, H', W')
    mu_x, mu_y, xx, yy, xy = blurred
    var_x = xx - mu_x**2
    var_y = yy - mu_y**2
    cov = xy - mu_x * mu_y
    c1, c2 = (k1 * data_range) ** 2, (k2 * data_range) ** 2
    num = (2 * mu_x * mu_y + c1) * (2 * cov + c2)
    s = num / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))  # SSIM map (N C, H', W')
    per_image: Tensor = s.reshape(n, -1).mean(1)
    return per_image


def depth_metrics(pred: Tensor, gt: Tensor, valid: Tensor | None = None) -> dict[str, float]:
    """AbsRel, RMSE (metres) and delta < 1.25 over valid pixels (H, W).

    Valid = `valid` (bool, optional) and gt > 0 and both finite. Raises if no pixel is valid.
    """
    p, g = pred.double(), gt.double()
    m = torch.isfinite(p) & torch.isfinite(g) & (g > 0)
    if valid is not None:
        m &= valid.bool()
    if not m.any():
        raise DataError("depth_metrics: no valid ground-truth pixel")
    p, g = p[m].clamp_min(1e-6), g[m]
    ratio = torch.maximum(p / g, g / p)
    return {"abs_rel": ((p - g).abs() / g).mean().item(),
            "rmse": ((p - g) ** 2).mean().sqrt().item(),
            "delta1": (ratio < 1.25).double().mean().item()}
