"""Guided Euler sampler: exact on a constant field, CFG identities, adapter run once per query."""

from __future__ import annotations

import torch
from torch import Tensor

from model.net import Condition, M3GDNet
from model.sampler import guided_condition, guided_velocity, sample
from tests.model.model_fixtures import make_batch, tiny_cfg
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
