"""Sample target views, decode them with the frozen image decoder, score them.

Latents in a batch are normalized per channel (`model.dataset`); they are mapped back with
the cached (mean, std) before decoding. Only target views are decoded and scored; the source
views generated alongside are discarded (paper, "Inference").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from model.encoders.base import ImageDecoder
from model.metrics import psnr, ssim
from model.sampler import VelocityModel, sample
from schemas.errors import DataError


@dataclass
class TargetResult:
    """One synthesized target view: its clip, view index, images and scores."""

    clip_id: int
    view: int
    pred: np.ndarray  # (h, w, 3) uint8
    gt: np.ndarray  # (h, w, 3) uint8
    psnr: float
    ssim: float


def denormalize(z: Tensor, mean: np.ndarray, std: np.ndarray) -> Tensor:
    """z * std + mean per channel: z (..., C, H, W), mean/std (C,) -> float32 (..., C, H, W)."""
    m = torch.as_tensor(mean, dtype=torch.float32)[:, None, None]
    s = torch.as_tensor(std, dtype=torch.float32)[:, None, None]
    return z.float() * s + m


def image_scores(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """(PSNR dB, SSIM) of two uint8 images (h, w, 3), scored on [0, 1] floats."""
    p = torch.from_numpy(pred).permute(2, 0, 1).double() / 255.0  # (3, h, w)
    g = torch.from_numpy(gt).permute(2, 0, 1).double() / 255.0
    return psnr(p, g), ssim(p, g)


def synthesize_targets(net: VelocityModel, batch: dict[str, Tensor], decoder: ImageDecoder,
                       mean: np.ndarray, std: np.ndarray, steps: int = 10,
                       guidance: float = 1.5, generator: torch.Generator | None = None,
                       tol: float | None = None) -> list[TargetResult]:
    """Sample a batch, decode every target view and score it against batch['images'].

    batch needs 'images' (B, V, h, w, 3) uint8 (stream with `with_images=True`) and
    optionally 'clip_id' (B,). Returns one `TargetResult` per target view, batch-major.
    """
    if "images" not in batch:
        raise DataError("synthesize_targets: batch has no 'images' (use with_images=True)")
    z_0 = sample(net, batch, steps, guidance, generator, tol).z_0  # (B, V, C, H, W)
    is_tgt = batch["is_target"]
    b_idx, v_idx = torch.nonzero(is_tgt, as_tuple=True)  # target entries, batch-major
    lat = denormalize(z_0[b_idx, v_idx], mean, std)  # (M, C, H, W)
    images = decoder.decode(lat.numpy())  # (M, h, w, 3) uint8
    clip_ids = batch.get("clip_id", torch.arange(is_tgt.shape[0]))
    out = []
    for k, (b, v) in enumerate(zip(b_idx.tolist(), v_idx.tolist(), strict=True)):
        gt = batch["images"][b, v].numpy()
        p, s = image_scores(images[k], gt)
        out.append(TargetResult(int(clip_ids[b]), v, images[k], gt, p, s))
    return out
