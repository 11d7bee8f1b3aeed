"""Guided Euler sampler (paper eq. 13 and "Inference").

All V view latents start from noise z_1 ~ N(0, I) and are integrated jointly from t = 1 to
t = 0 in K Euler steps of size 1/K with the guided velocity
v_cfg = v(z_t, t, null) + s (v(z_t, t, y) - v(z_t, t, null)), s = 1.5, where the null
condition drops the camera and all packets jointly and keeps the source latents. The
condition (adapter included) is built once per query for y and null stacked on the batch
axis, and reused at every step. Source-view outputs are generated alongside and discarded
by the caller.

Adaptive option (tol): after each step the Euler jump to t = 0, z_0_hat = z_t - t v, is
compared with the previous step's; once ||dz_0_hat|| <= tol ||z_0_hat|| the sampler returns
z_0_hat, i.e. finishes the remaining interval in one Euler step.

Temperature tau (Glow's reduced-temperature sampling): the start is z_1 = tau * eps with
eps ~ N(0, I). tau = 1 is the paper's sampler (a draw from the model's distribution);
tau < 1 trades sample diversity for accuracy: for Gaussian data x ~ N(mu, sigma^2) and the
exact velocity the flow maps z_1 to mu + sigma z_1, so tau scales the spread of the samples
around the conditional mean by tau, and tau = 0 returns that mean (the deterministic
sampler a PSNR score rewards). The same eps is drawn whatever tau is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch
from torch import Tensor

from model.net import Condition
from schemas.errors import DataError


class VelocityModel(Protocol):
    """What the sampler needs from a network (`model.net.M3GDNet` satisfies it)."""

    def condition(self, batch: dict[str, Tensor], drop_cam: Tensor,
                  drop_lidar: Tensor) -> Condition: ...

    def velocity(self, z_t: Tensor, t: Tensor, cond: Condition) -> Tensor: ...


@dataclass
class SampleResult:
    """z_0 (B, V, C, H, W) generated latents; steps taken and network evaluations (batched)."""

    z_0: Tensor
    steps: int
    nfe: int


def guided_condition(net: VelocityModel, batch: dict[str, Tensor], guidance: float) -> Condition:
    """[y ; null] stacked on the batch axis (2B), or y alone if guidance == 1; one adapter call."""
    B, dev = batch["is_target"].shape[0], batch["is_target"].device
    if guidance == 1.0:
        off = torch.zeros(B, dtype=torch.bool, device=dev)
        return net.condition(batch, off, off)
    flags = torch.cat([torch.zeros(B, dtype=torch.bool, device=dev),
                       torch.ones(B, dtype=torch.bool, device=dev)])
    twice = {k: torch.cat([v, v]) for k, v in batch.items() if isinstance(v, Tensor)}
    return net.condition(twice, flags, flags)


def guided_velocity(net: VelocityModel, z_t: Tensor, t: Tensor, cond: Condition,
                    guidance: float) -> Tensor:
    """Eq. 13 from a condition built by `guided_condition`: z_t (B, V, C, H, W), t (B,)."""
    if cond.c_tilde.shape[0] == z_t.shape[0]:  # y only (guidance == 1)
        return net.velocity(z_t, t, cond)
    v = net.velocity(torch.cat([z_t, z_t]), torch.cat([t, t]), cond)  # (2B, V, C, H, W)
    v_cond, v_null = v.chunk(2)
    return v_null + guidance * (v_cond - v_null)


def check_temperature(temperature: float) -> None:
    """A DataError unless 0 <= temperature < inf (the start noise's scale)."""
    if not math.isfinite(temperature) or temperature < 0:
        raise DataError(f"temperature must be finite and >= 0, got {temperature}")


@torch.inference_mode()
def sample(net: VelocityModel, batch: dict[str, Tensor], steps: int = 10,
           guidance: float = 1.5, generator: torch.Generator | None = None,
           tol: float | None = None, z_1: Tensor | None = None, temperature: float = 1.0
           ) -> SampleResult:
    """Integrate noise (t = 1) to data (t = 0) in `steps` Euler steps (fewer if tol stops it).

    The start is temperature * z_1 (z_1 drawn from N(0, I) on `generator` when None).
    """
    if steps < 1:
        raise DataError(f"steps must be >= 1, got {steps}")
    check_temperature(temperature)
    lat = batch["latents"]
    if z_1 is None:  # drawn on the CPU generator: the same noise on every device
        z_1 = torch.randn(lat.shape, generator=generator, dtype=lat.dtype)
    if temperature != 1.0:
        z_1 = z_1 * temperature
    z = z_1.to(lat.device)
    cond = guided_condition(net, batch, guidance)  # the adapter runs here, once
    prev: Tensor | None = None
    for k in range(steps):
        t_val = 1.0 - k / steps
        t = torch.full((z.shape[0],), t_val, device=z.device)
        v = guided_velocity(net, z, t, cond, guidance)
        if tol is not None:
            z0_hat = z - t_val * v  # Euler jump to t = 0
            if prev is not None and (z0_hat - prev).norm() <= tol * z0_hat.norm():
                return SampleResult(z0_hat, k + 1, k + 1)
            prev = z0_hat
        z = z - v / steps  # dt = -1/K
    return SampleResult(z, steps, steps)
