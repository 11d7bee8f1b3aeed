"""The warp packet modes (schemas.modes): reprojected source latents as target channels."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from model.adapter import (
    ResidualAdapter,
    build_packet,
    packet_channels,
    warp_channels,
    warp_for,
)
from model.net import M3GDNet
from model.train_step import TrainConfig, Trainer
from schemas.channels import n_g
from schemas.errors import DataError
from tests.model.model_fixtures import C_U, GRID, IMAGE, C, fixed_loss, make_batch, tiny_cfg

INV_DEPTH, VALID = 2, 0


def _identity_batch(depth_m: float = 2.0) -> dict[str, torch.Tensor]:
    """One clip of 2 views (source, target) with identical cameras and a full-support g."""
    b = make_batch(B=1, V=2, seed=4)
    b["T_world_cam"] = torch.eye(4, dtype=torch.float64).expand(1, 2, 4, 4).clone()
    g = torch.zeros(1, 2, n_g(), *GRID)
    g[:, :, VALID], g[:, :, INV_DEPTH] = 1.0, 1.0 / depth_m
    b["g"] = g
    return b


def test_identity_poses_give_the_source_latent_exactly() -> None:
    b = _identity_batch()
    w = warp_channels(b["latents"], b["g"], b["K"], b["T_world_cam"], b["is_target"], IMAGE)
    assert w.shape == (1, 2, *GRID, C + 1) and w.dtype == torch.float32
    assert torch.equal(w[0, 1, ..., :C], b["latents"][0, 0].movedim(0, -1))  # closed form
    assert torch.equal(w[0, 1, ..., C], torch.ones(GRID))  # every cell valid
    assert not w[0, 0].any()  # the source view gets no warp channels


def test_cells_without_support_are_invalid_and_zero() -> None:
    b = _identity_batch()
    b["g"][0, 1, VALID, 0, :] = 0.0  # the target's first row has no LiDAR support
    w = warp_channels(b["latents"], b["g"], b["K"], b["T_world_cam"], b["is_target"], IMAGE)
    assert not w[0, 1, 0].any()
    assert torch.equal(w[0, 1, 1:, :, C], torch.ones(GRID[0] - 1, GRID[1]))


def test_a_shifted_camera_shifts_the_warp_by_whole_cells() -> None:
    """Target camera 1 cell (14 px at depth 2 m: 14 * 2 / 60 m) to the right of the source:
    target cell (i, j) sees source cell (i, j + 1); the last column leaves the source image."""
    b = _identity_batch()
    px = IMAGE[1] / GRID[1]
    b["T_world_cam"][0, 1, 0, 3] = px * 2.0 / float(b["K"][0, 1, 0, 0])
    w = warp_channels(b["latents"], b["g"], b["K"], b["T_world_cam"], b["is_target"], IMAGE)
    src = b["latents"][0, 0].movedim(0, -1)
    assert torch.allclose(w[0, 1, :, :-1, :C], src[:, 1:])
    assert not w[0, 1, :, -1].any()


def test_target_latents_never_reach_the_warp() -> None:
    b = _identity_batch()
    w = warp_channels(b["latents"], b["g"], b["K"], b["T_world_cam"], b["is_target"], IMAGE)
    b["latents"][:, 1] = 1e3
    w2 = warp_channels(b["latents"], b["g"], b["K"], b["T_world_cam"], b["is_target"], IMAGE)
    assert torch.equal(w, w2)


@pytest.mark.parametrize(("mode", "p"), [("warp", 6 + C + 1), ("full_warp", 6 + C_U + C + 1)])
def test_shapes_and_dtypes_through_the_adapter(mode: str, p: int) -> None:
    b = make_batch()
    assert packet_channels(mode, C_U, C) == p
    phi = ResidualAdapter(C, C_U, mode, hidden=16, grid_hw=GRID)
    assert phi.conv_in.in_features == C + p + 1
    warp = warp_for(mode, b, IMAGE)
    assert warp is not None and warp.dtype == b["latents"].dtype
    ell = build_packet(mode, b["g"], b["h"], C_U, b["latents"], phi.learned, warp)
    assert ell is not None and ell.shape == (2, 3, *GRID, p) and ell.dtype == torch.float32
    assert torch.equal(ell[..., :6], b["g"].movedim(2, -1))  # g first, as in the paper modes
    if mode == "full_warp":
        assert torch.equal(ell[..., 6:6 + C_U], b["h"])
    assert torch.equal(ell[..., -(C + 1):], warp)
    out = phi(b["latents"], ell, b["is_target"])
    assert out.shape == b["latents"].shape and out.dtype == torch.float32
    src = ~b["is_target"]
    assert torch.equal(out[src], b["latents"][src])  # identity at init, as every mode


def test_a_warp_mode_without_its_inputs_is_one_line() -> None:
    b = make_batch()
    with pytest.raises(DataError, match="warp channels"):
        build_packet("warp", b["g"], None, C_U, b["latents"])
    del b["g"]
    with pytest.raises(DataError, match="needs the batch's g"):
        warp_for("warp", b, IMAGE)
    assert warp_for("full", b, IMAGE) is None
    with pytest.raises(DataError, match="latent channels"):
        packet_channels("warp", C_U)



@pytest.mark.parametrize("mode", ["warp", "full_warp"])
def test_one_batch_overfit_in_warp_mode(mode: str) -> None:
    """30 updates on one batch, as tests/model/test_train_step's overfit of full."""
    tr = Trainer(tiny_cfg(mode), TrainConfig(lr=2e-3, p_cam=0.0, p_lidar=0.0, seed=1))
    batch = make_batch(B=2, V=3, seed=5)
    before = fixed_loss(tr, batch)
    for _ in range(30):
        tr.step(batch)
    after = fixed_loss(tr, batch)
    assert after < 0.5 * before, (before, after)


def test_checkpoint_round_trip_keeps_the_mode(tmp_path: Path) -> None:
    tr = Trainer(tiny_cfg("warp"), TrainConfig(lr=1e-3, seed=0))
    b = make_batch(seed=2)
    del b["h"]
    tr.step(b)
    tr.save(tmp_path / "ck")
    back = Trainer.load(tmp_path / "ck")
    assert back.net.cfg.mode == "warp" and back.net.adapter.p == 6 + C + 1
    off = torch.zeros(2, dtype=torch.bool)
    z, t = torch.randn_like(b["latents"]), torch.full((2,), 0.5)
    with torch.no_grad():
        assert torch.equal(tr.net(b, z, t, off, off), back.net(b, z, t, off, off))


GOLDEN = {  # (sum, abs sum) measured at commit 932af40, before the warp modes existed
    "full": (-578.3514334256761, 3198.7312448346056),
    "geom_only": (-174.91717061947566, 2057.355431740056),
    "zero": (-577.961958077969, 3197.396008967655),
    "learnable": (154.0717421641457, 1986.9979856938007),
    "no_lidar": (74.83455016184598, 2237.0348601015285),
}


@pytest.mark.parametrize("mode", list(GOLDEN))
def test_the_paper_modes_compute_what_they_did(mode: str) -> None:
    """Every weight random (seeded), so the packet reaches the output."""
    torch.manual_seed(0)
    net = M3GDNet(tiny_cfg(mode))
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(0.1 * torch.randn(p.shape, generator=gen))
    b = make_batch(seed=3)
    z, t = torch.randn(b["latents"].shape, generator=gen), torch.rand(2, generator=gen)
    f = torch.zeros(2, dtype=torch.bool)
    with torch.no_grad():
        out = net(b, z, t, f, f).double()
    assert float(out.sum()) == pytest.approx(GOLDEN[mode][0], rel=1e-4)
    assert float(out.abs().sum()) == pytest.approx(GOLDEN[mode][1], rel=1e-4)


def test_untrained_reprojection_anchored_net_samples_the_reprojection() -> None:
    """anchor 'reprojection': with the zero-initialized output the untrained model *is* the
    LiDAR reprojection where a source filled the cell and copy-nearest-source elsewhere, at
    every K and guidance (the anchor is kept under the null condition)."""
    from model.camera import nearest_source_views
    from model.net import NetConfig
    from model.sampler import sample

    b = _identity_batch()
    px = IMAGE[1] / GRID[1]
    b["T_world_cam"][0, 1, 0, 3] = px * 2.0 / float(b["K"][0, 1, 0, 0])  # one cell right
    net = M3GDNet(NetConfig(**{**tiny_cfg("warp").to_json(), "anchor": "reprojection"})).eval()
    src = b["latents"][0, 0]  # (C, H, W)
    want = src.clone()
    want[:, :, :-1] = src[:, :, 1:]  # reprojected; the last column falls back to the source
    for steps, guidance in ((1, 1.0), (4, 1.0), (4, 1.5)):
        z_0 = sample(net, b, steps, guidance, generator=torch.Generator().manual_seed(0)).z_0
        assert torch.allclose(z_0[0, 1], want, atol=1e-5)
    assert int(nearest_source_views(b["T_world_cam"], b["is_target"])[0, 1]) == 0
    off = torch.ones(1, dtype=torch.bool)
    assert torch.equal(net.condition(b, off, off).anchor, net.condition(b, ~off, ~off).anchor)


def test_the_reprojection_anchor_needs_a_warp_mode_and_x_prediction() -> None:
    from model.net import NetConfig

    with pytest.raises(DataError, match="needs a warp packet mode"):
        M3GDNet(NetConfig(**{**tiny_cfg("full").to_json(), "anchor": "reprojection"}))
    with pytest.raises(DataError, match="needs prediction 'x'"):
        M3GDNet(NetConfig(**{**tiny_cfg("warp").to_json(), "anchor": "reprojection",
                             "prediction": "v"}))
