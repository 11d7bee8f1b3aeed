"""Linear-path flow matching (paper eqs. 1-3, 12) with the paper's convention.

z_0 is data (the clean joint latent of all V views), z_1 ~ N(0, I) is noise,
z_t = (1 - t) z_0 + t z_1 (eq. 1), u_t = dz_t/dt = z_1 - z_0 (eq. 2, data -> noise).
Sampling integrates dz/dt = v from t = 1 (noise) to t = 0 (data) (`model.sampler`).
The loss scores target-view entries only (eq. 12); camera and LiDAR conditioning are dropped
independently per clip with probability 0.1 each (classifier-free dropout).
"""

from __future__ import annotations

import torch
from torch import Tensor

from schemas.errors import DataError


def interpolate(z_0: Tensor, z_1: Tensor, t: Tensor) -> Tensor:
    """z_t = (1 - t) z_0 + t z_1: z_0, z_1 (B, V, C, H, W), t (B,) in [0, 1]."""
    t_ = t.to(z_0.dtype)[:, None, None, None, None]  # (B, 1, 1, 1, 1)
    return (1 - t_) * z_0 + t_ * z_1


def target_velocity(z_0: Tensor, z_1: Tensor) -> Tensor:
    """u_t = z_1 - z_0 (B, V, C, H, W); constant along the linear path."""
    return z_1 - z_0


def target_only_loss(v: Tensor, u: Tensor, is_target: Tensor) -> Tensor:
    """Mean squared error over target-view entries (eq. 12): v, u (B, V, C, H, W), is_target (B, V).

    The sum of squared errors under Omega_tgt is divided by the number of target entries,
    so the scale does not depend on the number of targets. Raises if no view is a target.
    """
    mask = is_target.to(v.dtype)[:, :, None, None, None]  # (B, V, 1, 1, 1) = Omega_tgt
    n = mask.sum() * v[0, 0].numel()
    if n == 0:
        raise DataError("target-only loss: the batch has no target view")
    return ((v.float() - u.float()) ** 2 * mask).sum() / n


def target_sq_error(v: Tensor, u: Tensor, is_target: Tensor, weight: Tensor | None = None
                    ) -> Tensor:
    """Sum of squared errors over target-view entries, each clip times weight (B,) (1 if None).

    Divided by the target entries of a whole global batch this is eq. 12's loss of that
    batch, however the batch is split over ranks and micro-batches.
    """
    mask = is_target.to(v.dtype)[:, :, None, None, None]  # (B, V, 1, 1, 1)
    if weight is not None:
        mask = mask * weight.to(v.dtype)[:, None, None, None, None]
    return ((v.float() - u.float()) ** 2 * mask).sum()


def sample_dropout(batch_size: int, p_cam: float, p_lidar: float,
                   generator: torch.Generator | None = None) -> tuple[Tensor, Tensor]:
    """Independent per-clip null masks (drop_cam, drop_lidar), each (B,) bool."""
    u = torch.rand(2, batch_size, generator=generator)
    return u[0] < p_cam, u[1] < p_lidar


T_SAMPLINGS = ("uniform", "logit_normal")
"""How training draws t: U(0, 1) (the paper) or sigmoid(N(mu, sigma)) (SD3, JiT)."""


def sample_t(n: int, how: str = "uniform", mu: float = 0.0, sigma: float = 1.0,
             generator: torch.Generator | None = None) -> Tensor:
    """n flow times in (0, 1): uniform, or logit-normal sigmoid(mu + sigma N(0, 1)).

    With t = 1 at the noise end, mu > 0 puts more samples on noisier t.
    """
    if how == "uniform":
        return torch.rand(n, generator=generator)
    if how == "logit_normal":
        return torch.sigmoid(mu + sigma * torch.randn(n, generator=generator))
    raise ValueError(f"unknown t sampling {how!r}; one of {T_SAMPLINGS}")


def sample_path(z_0: Tensor, generator: torch.Generator | None = None, how: str = "uniform",
                mu: float = 0.0, sigma: float = 1.0) -> tuple[Tensor, Tensor, Tensor]:
    """Draw t (B,) by `sample_t` and z_1 ~ N(0, I); return (t, z_t, u_t)."""
    t = sample_t(z_0.shape[0], how, mu, sigma, generator)
    z_1 = torch.randn(z_0.shape, generator=generator, dtype=z_0.dtype)
    return t, interpolate(z_0, z_1, t), target_velocity(z_0, z_1)


def sample_seed(seed: int, step: int, position: int) -> int:
    """Seed of the draws of one clip: run seed, update number, position in the global batch.

    The draws of a clip depend on these three only, so a global batch split over ranks,
    loader workers or gradient-accumulation micro-batches draws exactly what one process
    with the whole batch draws, and every rank draws different noise.
    """
    return (seed * 1_000_003 + step) * 1_000_033 + position


def per_sample_draws(shape: tuple[int, ...], seeds: list[int], how: str = "uniform",
                     mu: float = 0.0, sigma: float = 1.0, p_cam: float = 0.1,
                     p_lidar: float = 0.1) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """t (B,), z_1 (B, *shape), drop_cam (B,) bool, drop_lidar (B,) bool; sample b drawn on
    the CPU from its own generator seeded `seeds[b]` (same numbers on every device)."""
    ts, zs, drops = [], [], []
    for s in seeds:
        gen = torch.Generator().manual_seed(s)
        ts.append(sample_t(1, how, mu, sigma, gen))
        drops.append(torch.rand(2, generator=gen) < torch.tensor([p_cam, p_lidar]))
        zs.append(torch.randn(shape, generator=gen))
    if not seeds:
        return (torch.zeros(0), torch.zeros(0, *shape), torch.zeros(0, dtype=torch.bool),
                torch.zeros(0, dtype=torch.bool))
    d = torch.stack(drops)  # (B, 2)
    return torch.cat(ts), torch.stack(zs), d[:, 0], d[:, 1]
