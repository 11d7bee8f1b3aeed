"""Training modes (freeze, finetune, learnable packet, all-views loss, LiDAR dropout):
closed-form checks and one-batch overfits on tiny networks."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from model.flow import sample_path, target_only_loss
from model.train_step import TrainConfig, Trainer
from model.training_modes import TrainingRegime, adapted_state, freeze_for, start_from
from schemas.errors import DataError
from tests.model.model_fixtures import C, make_batch, tiny_cfg

CFG = TrainConfig(lr=2e-3, p_cam=0.0, p_lidar=0.0, seed=1)


def _fixed_loss(net: torch.nn.Module, batch: dict[str, torch.Tensor]) -> float:
    with torch.no_grad():
        t, z_t, u = sample_path(batch["latents"], torch.Generator().manual_seed(99))
        off = torch.zeros(batch["latents"].shape[0], dtype=torch.bool)
        v = net.velocity(z_t, t, net.condition(batch, off, off))  # type: ignore[operator]
        return float(target_only_loss(v, u, batch["is_target"]))


def _no_lidar_checkpoint(tmp_path: Path, steps: int = 3) -> Path:
    """A briefly trained no_lidar network, saved."""
    tr = Trainer(tiny_cfg("no_lidar"), CFG)
    batch = make_batch(B=2, V=3, seed=5)
    for _ in range(steps):
        tr.step(batch)
    tr.save(tmp_path / "no_lidar")
    return tmp_path / "no_lidar"


def _started(mode: str, training_mode: str, ckpt: Path) -> Trainer:
    cfg = tiny_cfg(mode)
    tr = Trainer(cfg, replace(CFG, training_mode=training_mode, init_from=str(ckpt)))
    start_from(tr.net, tr.ema, ckpt, C, cfg.to_json())
    return tr


def test_started_from_no_lidar_computes_the_no_lidar_network(tmp_path: Path) -> None:
    """Zero packet-input columns: at step 0 a full-packet network started from a no_lidar
    checkpoint returns exactly the no_lidar network's velocity."""
    ckpt = _no_lidar_checkpoint(tmp_path)
    src = Trainer.load(ckpt).net.eval()
    batch = make_batch(B=2, V=3, seed=11)
    for mode in ("full", "geom_only", "learnable", "no_lidar"):
        tr = _started(mode, "freeze", ckpt)
        assert _fixed_loss(tr.net.eval(), batch) == pytest.approx(_fixed_loss(src, batch),
                                                                  rel=1e-6), mode


def test_freeze_leaves_the_backbone_bit_identical_and_trains_the_adapter(
        tmp_path: Path) -> None:
    ckpt = _no_lidar_checkpoint(tmp_path)
    tr = _started("full", "freeze", ckpt)
    before = {k: v.clone() for k, v in tr.net.state_dict().items()}
    batch = make_batch(B=2, V=3, seed=5)
    for _ in range(4):
        tr.step(batch)
    after = tr.net.state_dict()
    for name, value in before.items():
        if name.startswith("adapter."):
            continue
        assert torch.equal(after[name], value), name
    assert any(not torch.equal(after[n], before[n]) for n in before if n.startswith("adapter."))
    ema = tr.ema.state_dict()
    assert all(torch.equal(ema[n], before[n]) for n in before if not n.startswith("adapter."))


def test_finetune_trains_the_backbone_too(tmp_path: Path) -> None:
    ckpt = _no_lidar_checkpoint(tmp_path)
    tr = _started("full", "finetune", ckpt)
    name = next(n for n, _ in tr.net.named_parameters() if n.startswith("backbone."))
    before = tr.net.state_dict()[name].clone()
    for _ in range(2):
        tr.step(make_batch(B=2, V=3, seed=5))
    assert not torch.equal(tr.net.state_dict()[name], before)


def test_freeze_is_recorded_and_survives_a_resume(tmp_path: Path) -> None:
    ckpt = _no_lidar_checkpoint(tmp_path)
    tr = _started("full", "freeze", ckpt)
    tr.step(make_batch(B=2, V=3, seed=5))
    tr.save(tmp_path / "frozen")
    again = Trainer.load(tmp_path / "frozen")
    assert again.cfg.training_mode == "freeze" and again.cfg.init_from == str(ckpt)
    trainable = {n for n, p in again.net.named_parameters() if p.requires_grad}
    assert trainable and all(n.startswith("adapter.") for n in trainable)


def test_init_from_refuses_a_packet_checkpoint_and_another_size(tmp_path: Path) -> None:
    tr = Trainer(tiny_cfg("full"), CFG)
    tr.save(tmp_path / "full")
    with pytest.raises(DataError, match="needs a no_lidar checkpoint"):
        _started("full", "freeze", tmp_path / "full")
    ckpt = _no_lidar_checkpoint(tmp_path, steps=1)
    wide = replace(tiny_cfg("full"), adapter_hidden=16)
    tr = Trainer(wide, CFG)
    with pytest.raises(DataError, match="adapter_hidden"):
        start_from(tr.net, tr.ema, ckpt, C, wide.to_json())


def test_adapted_state_keeps_latent_and_role_columns() -> None:
    src = {"adapter.conv_in.weight": torch.arange(2 * (C + 1), dtype=torch.float32).reshape(2, -1)}
    tgt = {"adapter.conv_in.weight": torch.ones(2, C + 4 + 1)}
    w = adapted_state(src, tgt, C)["adapter.conv_in.weight"]
    assert torch.equal(w[:, :C], src["adapter.conv_in.weight"][:, :C])
    assert torch.equal(w[:, -1], src["adapter.conv_in.weight"][:, -1])
    assert torch.equal(w[:, C:-1], torch.zeros(2, 4))


def test_learnable_packet_receives_gradient_and_overfits_one_batch() -> None:
    """The learned tensor gets a gradient once the adapter's zero-initialized output layer
    has moved (from the second update on), and one batch is fitted."""
    tr = Trainer(tiny_cfg("learnable"), CFG)
    learned = tr.net.adapter.learned
    assert learned is not None and learned.shape == (4, 6, 6 + 5)
    start = learned.detach().clone()
    batch = make_batch(B=2, V=3, seed=5)
    first = _fixed_loss(tr.net, batch)
    for _ in range(30):
        tr.step(batch)
    assert learned.grad is not None and learned.grad.abs().sum() > 0
    assert not torch.equal(learned.detach(), start)
    assert _fixed_loss(tr.net, batch) < 0.8 * first


def test_learnable_packet_is_data_independent_and_nulled_by_lidar_dropout() -> None:
    net = Trainer(tiny_cfg("learnable"), CFG).net
    with torch.no_grad():
        net.adapter.conv_out.weight.normal_()  # make the packet visible in c~
    a, b = make_batch(B=2, V=3, seed=1), make_batch(B=2, V=3, seed=1)
    b["g"], b["h"] = b["g"] * 7 + 3, b["h"] * -2  # other LiDAR data: must not matter
    off = torch.zeros(2, dtype=torch.bool)
    ca, cb = net.condition(a, off, off), net.condition(b, off, off)
    assert torch.equal(ca.c_tilde, cb.c_tilde)
    dropped = net.condition(a, off, ~off).c_tilde
    zero = Trainer(replace(tiny_cfg("learnable")), CFG).net  # same init
    zero.load_state_dict(net.state_dict())
    with torch.no_grad():
        assert net.adapter.learned is not None
        zero.adapter.learned.zero_()  # type: ignore[union-attr]
    assert torch.allclose(dropped, zero.condition(a, off, off).c_tilde)
    assert not torch.allclose(dropped, ca.c_tilde)


def test_all_views_loss_equals_target_only_loss_when_every_view_is_a_target() -> None:
    batch = make_batch(B=2, V=3, seed=3, n_targets=3)
    target = Trainer(tiny_cfg(), TrainConfig(seed=4))
    every = Trainer(tiny_cfg(), TrainConfig(seed=4, loss_views="all"))
    same = float(target.loss(batch).detach())
    assert float(every.loss(batch).detach()) == pytest.approx(same, rel=1e-6)
    mixed = make_batch(B=2, V=3, seed=3, n_targets=1)
    other = float(target.loss(mixed).detach())
    assert float(every.loss(mixed).detach()) != pytest.approx(other, rel=1e-3)


def test_all_views_loss_uses_the_global_view_count() -> None:
    """With the data plan's counts, the loss is the squared error over every view divided by
    the global batch's views (not its targets)."""
    batch = make_batch(B=2, V=3, seed=3, n_targets=1)
    every = Trainer(tiny_cfg(), TrainConfig(seed=4, loss_views="all"))
    alone = float(every.loss(batch).detach())
    planned = {**batch, "_n_targets": torch.tensor(2), "_n_views": torch.tensor(12)}
    assert float(every.loss(planned).detach()) == pytest.approx(alone * 6 / 12, rel=1e-6)


def test_regime_checks_and_records() -> None:
    with pytest.raises(DataError, match="needs --init-from"):
        TrainingRegime("freeze").check()
    with pytest.raises(DataError, match="takes no --init-from"):
        TrainingRegime("scratch", Path("x")).check()
    with pytest.raises(DataError, match="unknown loss views"):
        TrainingRegime(loss_views="sources").check()
    with pytest.raises(DataError, match="unknown loss space"):
        TrainingRegime(loss_space="z").check()
    fields = TrainingRegime("finetune", Path("ck"), "all", lidar_dropout=False,
                            loss_space="x").train_fields()
    assert fields == {"training_mode": "finetune", "init_from": "ck", "loss_views": "all",
                      "loss_space": "x", "p_lidar": 0.0}
    assert TrainingRegime().train_fields()["p_lidar"] == 0.1
    with pytest.raises(DataError, match="unknown training mode"):
        freeze_for(torch.nn.Linear(1, 1), "thaw")
