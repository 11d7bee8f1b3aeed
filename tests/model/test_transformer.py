"""Multi-view transformer and full network: shapes, presets, zero-init, world-frame invariance."""

from __future__ import annotations

import torch

from model.camera import nearest_source_views
from model.net import M3GDNet, NetConfig
from model.transformer import PRESETS, MultiViewDiT
from tests.model.model_fixtures import make_batch, random_pose, tiny_cfg


def _perturb(net: torch.nn.Module, seed: int) -> None:
    """Give zero-initialized layers random weights so outputs are non-trivial."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.05 * torch.randn(p.shape, generator=gen))


def test_velocity_shape_and_zero_output_at_init() -> None:
    torch.manual_seed(0)
    b = make_batch()
    off = torch.zeros(2, dtype=torch.bool)
    z_t, t = torch.randn_like(b["latents"]), torch.tensor([0.01, 0.6])
    gain = torch.tensor([0.05, 0.6])[:, None, None, None, None]
    src = nearest_source_views(b["T_world_cam"], b["is_target"])  # (B, V)
    anchor = b["latents"][torch.arange(2)[:, None], src]
    for prediction, anchored in (("v", "none"), ("x", "none"), ("x", "nearest_source")):
        net = M3GDNet(NetConfig(**{**tiny_cfg().to_json(), "prediction": prediction,
                                   "anchor": anchored}))
        v = net.velocity(z_t, t, net.condition(b, off, off))
        assert v.shape == b["latents"].shape
        if prediction == "v":  # adaLN-Zero + zero output layer: v = 0
            assert not v.any()
        elif anchored == "none":  # z0_hat = 0: v = z_t / max(t, 0.05)
            assert torch.allclose(v, z_t / gain)
        else:  # z0_hat = the nearest source's latent
            assert torch.allclose(v, (z_t - anchor) / gain)


def test_x_to_velocity_is_the_path_velocity_for_the_true_z0() -> None:
    from model.flow import interpolate
    from model.net import x_to_velocity

    gen = torch.Generator().manual_seed(0)
    z_0, z_1 = torch.randn(3, 2, 4, 2, 3, generator=gen), torch.randn(3, 2, 4, 2, 3, generator=gen)
    t = torch.tensor([0.05, 0.5, 1.0])
    v = x_to_velocity(interpolate(z_0, z_1, t), z_0, t)
    assert torch.allclose(v, z_1 - z_0, atol=1e-5)


def test_prediction_recorded_and_old_configs_read_as_v() -> None:
    cfg = tiny_cfg()
    assert cfg.prediction == "x" and NetConfig.from_json(cfg.to_json()) == cfg
    old = {k: v for k, v in cfg.to_json().items() if k not in ("prediction", "width", "depth")}
    assert NetConfig.from_json(old).prediction == "v"  # checkpoints from before the option
    try:
        M3GDNet(NetConfig(**{**cfg.to_json(), "prediction": "eps"}))
    except ValueError as err:
        assert "prediction" in str(err)
    else:
        raise AssertionError("an unknown prediction was accepted")


def test_invariant_to_global_rigid_transform_of_all_cameras() -> None:
    torch.manual_seed(0)
    net = M3GDNet(tiny_cfg()).eval()
    _perturb(net, 1)
    b = make_batch(seed=2)
    off = torch.zeros(2, dtype=torch.bool)
    z, t = torch.randn_like(b["latents"]), torch.tensor([0.3, 0.8])
    v = net.velocity(z, t, net.condition(b, off, off))
    G = random_pose(torch.Generator().manual_seed(5), scale=10.0)
    b2 = {**b, "T_world_cam": G @ b["T_world_cam"]}
    v2 = net.velocity(z, t, net.condition(b2, off, off))
    assert torch.allclose(v, v2, atol=1e-4)
    b3 = {**b, "T_world_cam": b["T_world_cam"].clone()}
    b3["T_world_cam"][:, 2] = G @ b3["T_world_cam"][:, 2]  # move the target only
    v3 = net.velocity(z, t, net.condition(b3, off, off))
    assert (v3 - v).abs().max() > 1e-3


def test_prope_option_changes_attention() -> None:
    torch.manual_seed(0)
    a = M3GDNet(tiny_cfg(prope=True))
    torch.manual_seed(0)
    b_ = M3GDNet(tiny_cfg(prope=False))
    b_.load_state_dict(a.state_dict())
    _perturb(a, 3)
    _perturb(b_, 3)
    b = make_batch()
    off = torch.zeros(2, dtype=torch.bool)
    z, t = torch.randn_like(b["latents"]), torch.rand(2)
    assert (a.velocity(z, t, a.condition(b, off, off))
            - b_.velocity(z, t, b_.condition(b, off, off))).abs().max() > 1e-4


def test_gld_preset_instantiates_on_meta() -> None:
    cfg = NetConfig(c=1536, c_u=1224, preset="gld")
    with torch.device("meta"):
        net = M3GDNet(cfg)
    n_backbone = sum(p.numel() for p in net.backbone.parameters())
    n_adapter = sum(p.numel() for p in net.adapter.parameters())
    assert 4e8 < n_backbone < 1e9  # DiT-XL class (~0.7 B with 2C-channel patch input)
    # paper: the adapter adds ~1.1 M parameters (2767 -> 256 -> 1536 1x1 convs)
    assert n_adapter == (1536 + 1230 + 1) * 256 + 256 + 256 * 1536 + 1536  # 1.10 M
    assert PRESETS["gld"].width == 1152


def test_tiny_preset_size() -> None:
    net = MultiViewDiT(8, (4, 6), PRESETS["tiny"])
    assert sum(p.numel() for p in net.parameters()) < 2e6
