"""Residual adapter (eq. 11): identity at init, target latents zeroed, modes, gradient flow."""

from __future__ import annotations

import pytest
import torch

from model.adapter import MODES, ResidualAdapter, build_packet, packet_channels, warp_for
from schemas.errors import DataError
from tests.model.model_fixtures import C_U, GRID, IMAGE, C, make_batch


@pytest.mark.parametrize("mode", MODES)
def test_identity_at_init_and_targets_zeroed(mode: str) -> None:
    b = make_batch()
    phi = ResidualAdapter(C, C_U, mode, hidden=16, grid_hw=GRID)
    ell = build_packet(mode, b["g"], b["h"], C_U, b["latents"], phi.learned,
                       warp_for(mode, b, IMAGE))
    out = phi(b["latents"], ell, b["is_target"])
    src = ~b["is_target"]
    assert torch.equal(out[src], b["latents"][src])  # c~ = c exactly at init
    assert torch.equal(out[b["is_target"]], torch.zeros_like(out[b["is_target"]]))  # c = 0


@pytest.mark.parametrize(("mode", "p"), [("full", 6 + C_U), ("geom_only", 6),
                                         ("zero", 6 + C_U), ("learnable", 6 + C_U),
                                         ("no_lidar", 0)])
def test_packet_channels_and_input_width(mode: str, p: int) -> None:
    assert packet_channels(mode, C_U) == p
    phi = ResidualAdapter(C, C_U, mode, grid_hw=GRID)
    assert phi.conv_in.in_features == C + p + 1
    b = make_batch()
    ell = build_packet(mode, b["g"], None if mode != "full" else b["h"], C_U, b["latents"],
                       phi.learned)
    assert (ell is None) == (mode == "no_lidar")
    if mode == "zero":
        assert ell is not None and ell.shape[-1] == p and not ell.any()


def test_gradients_flow_and_packet_matters_after_update() -> None:
    b = make_batch()
    adapter = ResidualAdapter(C, C_U, "full", hidden=16)
    ell = build_packet("full", b["g"], b["h"], C_U, b["latents"])
    assert ell is not None
    out = adapter(b["latents"], ell, b["is_target"])
    (out**2 + out).sum().backward()
    grad = adapter.conv_out.weight.grad
    assert grad is not None and grad.abs().sum() > 0
    with torch.no_grad():
        adapter.conv_out.weight -= 0.1 * grad
        a = adapter(b["latents"], ell, b["is_target"])
        z = adapter(b["latents"], torch.zeros_like(ell), b["is_target"])
    assert not torch.allclose(a, z)  # the packet now changes c~


def test_wrong_channels_rejected() -> None:
    b = make_batch()
    with pytest.raises(ValueError, match="C_u"):
        build_packet("full", b["g"], b["h"][..., :2], C_U, b["latents"])
    with pytest.raises(ValueError, match="unknown packet mode"):
        packet_channels("learned", C_U)


def test_packed_h_scatters_to_the_dense_packet() -> None:
    """h handed over packed (rows of the cells g[:, :, 0] > 0.5, row-major over (B, V, H, W),
    as the loader batches them) gives the same packet as dense h zero off those cells."""
    b = make_batch()
    occupied = torch.rand(b["g"][:, :, 0].shape, generator=torch.Generator().manual_seed(0)) < 0.4
    g = b["g"].clone()
    g[:, :, 0] = occupied.float()
    dense = b["h"] * occupied[..., None]
    rows = dense[occupied].half()
    packed = build_packet("full", g, rows, C_U, b["latents"])
    expected = build_packet("full", g, dense.half().float(), C_U, b["latents"])
    assert packed is not None and expected is not None
    torch.testing.assert_close(packed, expected, rtol=0, atol=0)
    with pytest.raises(ValueError, match="packed h rows"):
        build_packet("full", g, rows[1:], C_U, b["latents"])


def test_learnable_needs_its_tensor_of_the_packet_shape() -> None:
    b = make_batch()
    with pytest.raises(DataError, match="needs the latent grid"):
        ResidualAdapter(C, C_U, "learnable")
    with pytest.raises(DataError, match="needs the learned"):
        build_packet("learnable", None, None, C_U, b["latents"], torch.zeros(2, 2, 6 + C_U))
    learned = torch.randn(*GRID, 6 + C_U)
    ell = build_packet("learnable", None, None, C_U, b["latents"], learned)
    assert ell is not None and ell.shape == (*b["latents"].shape[:2], *GRID, 6 + C_U)
    assert torch.equal(ell[1, 2], learned)  # the same tensor for every clip and view


def test_dtau_channel_off_hides_delta_tau_and_nothing_else() -> None:
    from dataclasses import replace

    from model.net import M3GDNet
    from tests.model.model_fixtures import tiny_cfg

    torch.manual_seed(0)
    net = M3GDNet(replace(tiny_cfg("full"), dtau_channel=False))
    with torch.no_grad():
        net.adapter.conv_out.weight.normal_()
    a = make_batch()
    b = {**a, "g": a["g"].clone()}
    b["g"][:, :, 5] += 0.3  # another clock: only delta tau differs
    off = torch.zeros(2, dtype=torch.bool)
    assert torch.equal(net.condition(a, off, off).c_tilde, net.condition(b, off, off).c_tilde)
    c = {**a, "g": a["g"].clone()}
    c["g"][:, :, 4] += 0.3  # depth variance is still seen
    assert not torch.equal(net.condition(a, off, off).c_tilde,
                           net.condition(c, off, off).c_tilde)
    seen = M3GDNet(tiny_cfg("full"))
    seen.load_state_dict(net.state_dict())
    assert not torch.equal(seen.condition(a, off, off).c_tilde,
                           seen.condition(b, off, off).c_tilde)
