"""Guided Euler sampler: exact on a constant field, CFG identities, adapter run once per query."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor

from model.net import Condition, M3GDNet
from model.sampler import guided_condition, guided_velocity, sample
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
