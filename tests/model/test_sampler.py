"""Guided Euler sampler: exact on a constant field, CFG identities, adapter run once per query."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from model.net import Condition, M3GDNet
from model.sampler import guided_condition, guided_velocity, sample
from schemas.errors import DataError
from tests.model.model_fixtures import GRID, make_batch, random_pose, tiny_cfg
from tests.model.test_transformer import _perturb


class ConstantField:
    """v(z, t, y) = a for the conditional and b for the null condition."""

    def __init__(self, a: Tensor, b: Tensor) -> None:
        self.a, self.b, self.calls = a, b, 0

    def condition(self, batch: dict[str, Tensor], drop_cam: Tensor, drop_lidar: Tensor
                  ) -> Condition:
        B, V = batch["is_target"].shape
        null = drop_cam.float()[:, None, None, None, None]  # (B, 1, 1, 1, 1)
        return Condition(null.expand(B, V, 1, 1, 1), torch.zeros(B), torch.zeros(B), drop_cam)

    def velocity(self, z_t: Tensor, t: Tensor, cond: Condition) -> Tensor:
        self.calls += 1
        null = cond.c_tilde[:, :, :1, :1, :1]
        reps = (z_t.shape[0] // self.a.shape[0], 1, 1, 1, 1)  # [y ; null] doubles the batch
        return (1 - null) * self.a.repeat(reps) + null * self.b.repeat(reps) + 0 * z_t


def test_constant_velocity_integrates_exactly() -> None:
    b = make_batch()
    a = torch.randn(b["latents"].shape)
    z_1 = torch.randn(b["latents"].shape)
    for steps in (1, 4, 7):
        res = sample(ConstantField(a, a), b, steps=steps, guidance=1.5, z_1=z_1)
        assert torch.allclose(res.z_0, z_1 - a, atol=1e-5) and res.steps == steps


def test_guidance_formula_on_constant_fields() -> None:
    b = make_batch()
    a, n = torch.randn(b["latents"].shape), torch.randn(b["latents"].shape)
    z_1 = torch.randn(b["latents"].shape)
    res = sample(ConstantField(a, n), b, steps=3, guidance=1.5, z_1=z_1)
    assert torch.allclose(res.z_0, z_1 - (n + 1.5 * (a - n)), atol=1e-5)


def test_adaptive_stops_early_on_constant_field() -> None:
    b = make_batch()
    a, z_1 = torch.randn(b["latents"].shape), torch.randn(b["latents"].shape)
    res = sample(ConstantField(a, a), b, steps=20, tol=1e-4, z_1=z_1)
    assert res.steps == 2 and torch.allclose(res.z_0, z_1 - a, atol=1e-5)


def _net() -> M3GDNet:
    torch.manual_seed(0)
    net = M3GDNet(tiny_cfg()).eval()
    _perturb(net, 4)
    return net


def test_cfg_with_s_one_equals_conditional() -> None:
    net, b = _net(), make_batch()
    z, t = torch.randn_like(b["latents"]), torch.tensor([0.4, 0.9])
    off = torch.zeros(2, dtype=torch.bool)
    with torch.no_grad():
        v_c = net.velocity(z, t, net.condition(b, off, off))
        both = guided_condition(net, b, guidance=1.5)  # [y ; null]
        v_s1 = guided_velocity(net, z, t, both, guidance=1.0)
        v_s15 = guided_velocity(net, z, t, both, guidance=1.5)
    assert torch.allclose(v_s1, v_c, atol=1e-5)
    assert (v_s15 - v_c).abs().max() > 1e-4  # the null branch differs


def test_adapter_runs_once_per_query_and_targets_do_not_leak() -> None:
    net, b = _net(), make_batch()
    calls: list[int] = []
    net.adapter.register_forward_hook(lambda *_: calls.append(1))
    gen = torch.Generator().manual_seed(0)
    res = sample(net, b, steps=5, guidance=1.5, generator=gen)
    assert len(calls) == 1 and res.nfe == 5
    b2 = {**b, "latents": b["latents"].clone()}
    b2["latents"][b["is_target"]] = 7.0  # ground-truth target latents must not matter
    res2 = sample(net, b2, steps=5, guidance=1.5, generator=torch.Generator().manual_seed(0))
    assert torch.allclose(res.z_0, res2.z_0, atol=1e-6)
    assert torch.isfinite(res.z_0).all()


def _conds_equal(a: Condition, b: Condition, i: int) -> bool:
    """Clip i of two conditions is identical in every part."""
    return all(torch.equal(getattr(a, f)[i], getattr(b, f)[i])
               for f in ("c_tilde", "cam", "P", "P_inv"))


@pytest.mark.parametrize("mode", ["full", "geom_only"])
def test_null_lidar_equals_zeroed_packets(mode: str) -> None:
    torch.manual_seed(0)
    net = M3GDNet(tiny_cfg(mode)).eval()
    _perturb(net, 4)
    b = make_batch()
    off = torch.zeros(2, dtype=torch.bool)
    drop = torch.tensor([True, False])  # drop LiDAR of clip 0 only
    zeroed = {**b, "g": torch.zeros_like(b["g"]), "h": torch.zeros_like(b["h"])}
    with torch.no_grad():
        plain = net.condition(b, off, off)
        dropped = net.condition(b, off, drop)
        no_packets = net.condition(zeroed, off, off)
    assert _conds_equal(dropped, no_packets, 0)  # eq. 12's null packet: all channels zero
    assert _conds_equal(dropped, plain, 1)  # the other clip keeps its packets
    assert (plain.c_tilde[0] - dropped.c_tilde[0]).abs().max() > 1e-4  # packets did matter
    # a LiDAR drop leaves the camera part alone
    for f in ("cam", "P", "P_inv"):
        assert torch.equal(getattr(dropped, f), getattr(plain, f))


def test_null_camera_resets_plucker_and_projective_matrices() -> None:
    net, b = _net(), make_batch()
    off = torch.zeros(2, dtype=torch.bool)
    drop = torch.tensor([False, True])  # drop the camera of clip 1 only
    with torch.no_grad():
        plain = net.condition(b, off, off)
        dropped = net.condition(b, drop, off)
    eye = torch.eye(4).expand(3, 4, 4)
    assert not torch.allclose(plain.P[1], eye) and plain.cam[1, :, :6].abs().max() > 1e-3
    assert torch.equal(dropped.P[1], eye) and torch.equal(dropped.P_inv[1], eye)
    assert torch.equal(dropped.cam[1, :, :6], torch.zeros_like(dropped.cam[1, :, :6]))
    role = b["is_target"][1].float()[:, None, None].expand(3, *GRID)
    assert torch.equal(dropped.cam[1, :, 6], role)  # the role channel is kept
    assert dropped.cam.shape[2] == 7
    assert _conds_equal(dropped, plain, 0)
    assert torch.equal(dropped.c_tilde, plain.c_tilde)  # latents and packets are kept
    # with the camera dropped, v no longer depends on the poses or intrinsics of that clip
    z, t = torch.randn_like(b["latents"]), torch.tensor([0.4, 0.7])
    moved = {**b, "T_world_cam": b["T_world_cam"].clone(), "K": b["K"].clone()}
    moved["T_world_cam"][:, 1] = random_pose(torch.Generator().manual_seed(3)) @ \
        moved["T_world_cam"][:, 1]
    moved["K"][:, :, 0, 0] *= 1.5
    with torch.no_grad():
        v = net.velocity(z, t, dropped)
        v_moved = net.velocity(z, t, net.condition(moved, drop, off))
    assert torch.allclose(v[1], v_moved[1], atol=1e-6)
    assert (v[0] - v_moved[0]).abs().max() > 1e-4  # clip 0 still sees its cameras


def test_guided_null_half_drops_camera_and_lidar_jointly() -> None:
    net, b = _net(), make_batch()
    off, on = torch.zeros(2, dtype=torch.bool), torch.ones(2, dtype=torch.bool)
    zeroed = {**b, "g": torch.zeros_like(b["g"]), "h": torch.zeros_like(b["h"])}
    with torch.no_grad():
        both = guided_condition(net, b, guidance=1.5)  # [y ; null]
        y = net.condition(b, off, off)
        null = net.condition(zeroed, on, off)  # no packets, camera dropped
    for f in ("c_tilde", "cam", "P", "P_inv"):
        part_y, part_null = getattr(both, f).chunk(2)
        assert torch.allclose(part_y, getattr(y, f), atol=1e-6), f
        assert torch.allclose(part_null, getattr(null, f), atol=1e-6), f


class GaussianField:
    """The exact velocity E[z_1 - z_0 | z_t] for data z_0 ~ N(mu, sigma^2) elementwise.

    z_t = (1 - t) z_0 + t z_1 has variance (1 - t)^2 sigma^2 + t^2; the flow of this field
    maps z_1 to mu + sigma z_1 (an affine map between Gaussians), so the closed form of a
    sample at temperature tau is mu + sigma tau eps.
    """

    def __init__(self, mu: Tensor, sigma: Tensor) -> None:
        self.mu, self.sigma = mu.double(), sigma.double()

    def condition(self, batch: dict[str, Tensor], drop_cam: Tensor, drop_lidar: Tensor
                  ) -> Condition:
        return ConstantField(self.mu, self.mu).condition(batch, drop_cam, drop_lidar)

    def velocity(self, z_t: Tensor, t: Tensor, cond: Condition) -> Tensor:
        s = t.double()[:, None, None, None, None]  # (B, 1, 1, 1, 1)
        var = (1 - s) ** 2 * self.sigma ** 2 + s ** 2
        r = z_t.double() - (1 - s) * self.mu  # z_t minus its mean
        x_hat = self.mu + (1 - s) * self.sigma ** 2 / var * r  # E[z_0 | z_t]
        e_hat = s / var * r  # E[z_1 | z_t]
        return (e_hat - x_hat).to(z_t.dtype)


def _gaussian_case() -> tuple[dict[str, Tensor], GaussianField, Tensor]:
    b = make_batch()
    g = torch.Generator().manual_seed(3)
    shape = b["latents"].shape
    mu = torch.randn(shape, generator=g)
    sigma = 0.2 + 1.8 * torch.rand(shape, generator=g)
    b["latents"] = b["latents"].double()
    return b, GaussianField(mu, sigma), torch.randn(shape, generator=g, dtype=torch.float64)


@pytest.mark.parametrize(("tau", "steps"), [(0.0, 400), (0.25, 400), (1.0, 400),
                                           (1.0, 1600)])
def test_temperature_scales_the_spread_around_the_mean(tau: float, steps: int) -> None:
    """Closed form: K Euler steps of the exact Gaussian field land within 12 tau / K of
    mu + sigma tau eps (Euler's error is first order: measured 0.097, 0.024, 0.0061 at
    K = 100, 400, 1600 for tau = 1, |eps| up to 3.3); tau = 0 returns the mean itself."""
    b, field, eps = _gaussian_case()
    z_0 = sample(field, b, steps=steps, guidance=1.0, z_1=eps, temperature=tau).z_0
    want = field.mu + field.sigma * tau * eps
    assert (z_0 - want).abs().max().item() <= 12 * tau / steps + 1e-8
    if tau > 0:  # the sample's spread around the mean, in units of sigma, is tau
        spread = ((z_0 - field.mu) / field.sigma).std().item()
        assert abs(spread / (tau * eps.std().item()) - 1) < 0.01


def test_temperature_one_is_the_papers_sampler_and_zero_ignores_the_noise() -> None:
    b, net = make_batch(), _net()
    paper = sample(net, b, steps=3, generator=torch.Generator().manual_seed(1)).z_0
    same = sample(net, b, steps=3, generator=torch.Generator().manual_seed(1),
                  temperature=1.0).z_0
    assert torch.equal(paper, same)
    cold = [sample(net, b, steps=3, generator=torch.Generator().manual_seed(s),
                   temperature=0.0).z_0 for s in (1, 2)]
    assert torch.equal(cold[0], cold[1]) and not torch.equal(cold[0], paper)


@pytest.mark.parametrize("tau", [-0.1, float("nan"), float("inf")])
def test_temperature_outside_zero_to_finite_is_refused(tau: float) -> None:
    with pytest.raises(DataError, match="temperature must be finite and >= 0"):
        sample(_net(), make_batch(), steps=1, temperature=tau)
