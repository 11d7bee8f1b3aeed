"""Held-out flow-matching loss at a fixed t-grid with fixed noise (comparable across runs).

The training loss draws t and z_1 afresh every step, so two runs' loss curves differ by
sampling noise. Here every batch i is scored at each t of `T_GRID` with z_1 drawn from a
generator seeded by (seed, i): two networks scored on the same batches see exactly the same
(z_0, z_1, t), so their losses differ only by what they predict. Conditioning is kept (no
classifier-free dropout).

Closed forms for unit-Gaussian i.i.d. target latents independent of the conditioning
(per element, on the target entries):
  v = 0 (v-prediction at init: zero output layer)            loss 2
  z0_hat = 0 (x-prediction at init), t >= T_MIN              loss 1 / t^2
  the optimal blind predictor E[u | z_t] = (2t - 1) z_t / D  loss 1 / D,  D = (1 - t)^2 + t^2
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable

import torch
from torch import Tensor

from model.flow import interpolate, target_only_loss, target_velocity
from model.sampler import VelocityModel

T_GRID = (0.1, 0.3, 0.5, 0.7, 0.9)
"""Flow times of the validation loss (t = 1 is noise)."""


def blind_optimum_loss(t: float) -> float:
    """Per-element loss of E[u | z_t] on unit-Gaussian data: 1 / ((1 - t)^2 + t^2)."""
    return 1.0 / ((1.0 - t) ** 2 + t**2)


@torch.no_grad()
def t_binned_loss(net: VelocityModel, batches: Iterable[dict[str, Tensor]],
                  t_grid: tuple[float, ...] = T_GRID, seed: int = 0) -> dict[str, object]:
    """Mean target-only loss per t of `t_grid` over `batches` (model-batch dicts), fixed noise.

    Returns {"t": [...], "loss": [...] per t, "mean": mean over t}; every t weighs the same.
    """
    sums = [0.0] * len(t_grid)
    n = 0
    for i, batch in enumerate(batches):
        z_0 = batch["latents"].float()  # (B, V, C, H, W)
        B = z_0.shape[0]
        gen = torch.Generator().manual_seed(seed * 1_000_003 + i)
        z_1 = torch.randn(z_0.shape, generator=gen).to(z_0.device)  # drawn on the CPU
        off = torch.zeros(B, dtype=torch.bool, device=z_0.device)
        cond = net.condition(batch, off, off)
        u = target_velocity(z_0, z_1)
        for j, t_val in enumerate(t_grid):
            t = torch.full((B,), t_val, device=z_0.device)
            v = net.velocity(interpolate(z_0, z_1, t), t, cond)
            sums[j] += float(target_only_loss(v, u, batch["is_target"])) * B
        n += B
    if n == 0:
        raise ValueError("t_binned_loss: no batch")
    losses = [s / n for s in sums]
    return {"t": list(t_grid), "loss": losses, "mean": statistics.fmean(losses)}
