"""Flow matching path, velocity, target-only loss, dropout."""

from __future__ import annotations

import pytest
import torch

from model.flow import interpolate, sample_dropout, sample_path, target_only_loss, target_velocity


def test_path_endpoints_and_velocity_is_derivative() -> None:
    gen = torch.Generator().manual_seed(0)
    z_0, z_1 = torch.randn(2, 3, 4, 2, 2, generator=gen), torch.randn(2, 3, 4, 2, 2, generator=gen)
    assert torch.equal(interpolate(z_0, z_1, torch.zeros(2)), z_0)  # data at t = 0
    assert torch.equal(interpolate(z_0, z_1, torch.ones(2)), z_1)  # noise at t = 1
    t, h = torch.tensor([0.2, 0.7], dtype=torch.float64), 1e-3
    fd = (interpolate(z_0.double(), z_1.double(), t + h)
          - interpolate(z_0.double(), z_1.double(), t)) / h
    assert torch.allclose(fd, target_velocity(z_0, z_1).double(), atol=1e-6)


def test_loss_ignores_sources() -> None:
    gen = torch.Generator().manual_seed(1)
    v, u = torch.randn(2, 3, 4, 2, 2, generator=gen), torch.randn(2, 3, 4, 2, 2, generator=gen)
    tgt = torch.tensor([[False, False, True], [False, True, True]])
    loss = target_only_loss(v, u, tgt)
    v2 = v.clone()
    v2[~tgt] += 100.0  # change source predictions only
    assert torch.equal(target_only_loss(v2, u, tgt), loss)
    v3 = v.clone()
    v3[tgt] += 1.0
    assert target_only_loss(v3, u, tgt) > loss
    expected = ((v - u)[tgt] ** 2).mean()
    assert torch.allclose(loss, expected)


def test_loss_needs_a_target() -> None:
    with pytest.raises(ValueError, match="no target"):
        target_only_loss(torch.zeros(1, 2, 1, 1, 1), torch.zeros(1, 2, 1, 1, 1),
                         torch.zeros(1, 2, dtype=torch.bool))


def test_dropout_rates_independent() -> None:
    gen = torch.Generator().manual_seed(2)
    cam, lid = sample_dropout(20000, 0.1, 0.1, gen)
    assert abs(cam.float().mean() - 0.1) < 0.01 and abs(lid.float().mean() - 0.1) < 0.01
    assert abs((cam & lid).float().mean() - 0.01) < 0.004  # independent: p^2


def test_sample_path_consistent() -> None:
    gen = torch.Generator().manual_seed(3)
    z_0 = 3.0 * torch.randn(4000, 2, 4, 2, 2, generator=gen) + 5.0  # data: mean 5, std 3
    t, z_t, u = sample_path(z_0, torch.Generator().manual_seed(3))
    assert t.shape == (4000,) and z_t.shape == u.shape == z_0.shape
    # t ~ U(0, 1), one per clip: mean 1/2, variance 1/12, covering the whole interval
    assert bool(((t > 0) & (t < 1)).all())
    assert abs(float(t.mean()) - 0.5) < 0.015 and abs(float(t.var()) - 1 / 12) < 0.005
    assert float(t.min()) < 0.01 and float(t.max()) > 0.99
    assert abs(float((t < 0.25).float().mean()) - 0.25) < 0.03
    # u = z_1 - z_0 with fresh noise z_1 ~ N(0, I), independent of the data and of t
    z_1 = u + z_0
    assert abs(float(z_1.mean())) < 0.01 and abs(float(z_1.std()) - 1.0) < 0.01
    flat0, flat1 = z_0.flatten(), z_1.flatten()
    assert abs(float(torch.corrcoef(torch.stack([flat0, flat1]))[0, 1])) < 0.01
    per_clip = z_1.flatten(1)
    assert abs(float(torch.corrcoef(torch.stack([t, per_clip[:, 0]]))[0, 1])) < 0.05
    assert abs(float(torch.corrcoef(torch.stack([per_clip[:, 0], per_clip[:, 1]]))[0, 1])) < 0.05
    assert torch.allclose(z_t, interpolate(z_0, z_1, t), atol=1e-5)
    # seeded: the same generator state repeats the draw, another seed does not
    t2, z_t2, _ = sample_path(z_0, torch.Generator().manual_seed(3))
    t3, _, _ = sample_path(z_0, torch.Generator().manual_seed(4))
    assert torch.equal(t, t2) and torch.equal(z_t, z_t2) and not torch.equal(t, t3)


def test_logit_normal_t_sampling_shifts_towards_noise() -> None:
    from model.flow import sample_t

    gen = torch.Generator().manual_seed(0)
    t = sample_t(20000, "logit_normal", mu=1.0, sigma=1.0, generator=gen)
    assert t.min() > 0 and t.max() < 1
    assert abs(float(torch.logit(t).mean()) - 1.0) < 0.03  # logit(t) ~ N(1, 1)
    assert abs(float(torch.logit(t).std()) - 1.0) < 0.03
    u = sample_t(20000, "uniform", generator=gen)
    assert abs(float(u.mean()) - 0.5) < 0.01
    with pytest.raises(ValueError, match="t sampling"):
        sample_t(3, "beta")


def test_lr_schedule_warmup_then_cosine() -> None:
    from model.train_step import TrainConfig

    c = TrainConfig(lr=1e-3, warmup_steps=10, decay_steps=100, lr_min=1e-5)
    assert c.lr_at(0) == pytest.approx(1e-4) and c.lr_at(9) == pytest.approx(1e-3)
    assert c.lr_at(10) == pytest.approx(1e-3)
    assert c.lr_at(60) == pytest.approx(1e-5 + 0.5 * (1e-3 - 1e-5))
    assert c.lr_at(110) == pytest.approx(1e-5) and c.lr_at(500) == pytest.approx(1e-5)
    assert TrainConfig(lr=2e-4).lr_at(12345) == 2e-4  # constant by default (the paper's)
