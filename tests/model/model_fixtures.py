"""Tiny random batches and configs for the model tests."""

from __future__ import annotations

import torch
from torch import Tensor

from model.flow import sample_path, target_only_loss
from model.net import NetConfig
from model.train_step import Trainer

C, C_U, GRID, IMAGE = 8, 5, (4, 6), (56, 84)


def tiny_cfg(mode: str = "full", prope: bool = True) -> NetConfig:
    """Tiny-preset network on a 4 x 6 grid of 8-channel latents (56 x 84 px images)."""
    return NetConfig(c=C, c_u=C_U, grid_hw=GRID, image_hw=IMAGE, mode=mode, preset="tiny",
                     adapter_hidden=32, prope=prope)


def random_rotation(gen: torch.Generator) -> Tensor:
    """A random proper rotation (3, 3) float64."""
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=gen, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))
    return q if torch.det(q) > 0 else -q


def random_pose(gen: torch.Generator, scale: float = 2.0) -> Tensor:
    """A random rigid transform (4, 4) float64."""
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = random_rotation(gen)
    T[:3, 3] = scale * torch.randn(3, generator=gen, dtype=torch.float64)
    return T


def make_batch(B: int = 2, V: int = 3, seed: int = 0, n_targets: int = 1) -> dict[str, Tensor]:
    """Random batch in the trainer's format; the last `n_targets` views are targets."""
    gen = torch.Generator().manual_seed(seed)
    K = torch.tensor([[60.0, 0.0, 41.5], [0.0, 60.0, 27.5], [0.0, 0.0, 1.0]])
    T = torch.stack([torch.stack([random_pose(gen) for _ in range(V)]) for _ in range(B)])
    is_target = torch.zeros(B, V, dtype=torch.bool)
    is_target[:, V - n_targets:] = True
    return {
        "latents": torch.randn(B, V, C, *GRID, generator=gen),
        "g": torch.rand(B, V, 6, *GRID, generator=gen),
        "h": torch.randn(B, V, *GRID, C_U, generator=gen),  # channels-last
        "K": K.expand(B, V, 3, 3).clone(),
        "T_world_cam": T,
        "is_target": is_target,
    }


def fixed_loss(tr: Trainer, batch: dict[str, Tensor]) -> float:
    """eq. 12's loss of a trainer's network on `batch` at fixed (t, z_1), no dropout."""
    with torch.no_grad():
        t, z_t, u = sample_path(batch["latents"], torch.Generator().manual_seed(99))
        off = torch.zeros(batch["latents"].shape[0], dtype=torch.bool)
        v = tr.net.velocity(z_t, t, tr.net.condition(batch, off, off))
        return float(target_only_loss(v, u, batch["is_target"]))
