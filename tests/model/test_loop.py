"""Training loop on a tiny cache: runs through the stream, resumes mid-epoch exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from model.checkpoint import read_meta
from model.dataset import ClipStream
from model.loop import TrainingDiverged, resume, train_loop
from model.train_step import DivergedError, TrainConfig, Trainer
from tests.model.cache_fixture import random_cache, tiny_net


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return random_cache(tmp_path_factory)


def test_resume_mid_epoch_equals_straight(cache_dir: Path, tmp_path: Path) -> None:
    tcfg = TrainConfig(lr=1e-3, seed=3)
    straight = Trainer(tiny_net(), tcfg)
    losses = train_loop(straight, ClipStream(cache_dir, "train", "geom_only", seed=1), 5, 2)
    assert len(losses) == 5 and all(np.isfinite(losses))
    first = Trainer(tiny_net(), tcfg)
    train_loop(first, ClipStream(cache_dir, "train", "geom_only", seed=1), 3, 2,
               ckpt_dir=tmp_path / "ck")
    stream = ClipStream(cache_dir, "train", "geom_only", seed=1)
    again = resume(tmp_path / "ck")
    assert again.extra["stream"] == {"epoch": 0, "step": 3, "global_batch": 2}
    rest = train_loop(again, stream, 5, 2)
    assert rest == pytest.approx(losses[3:], abs=1e-6)
    for p, q in zip(straight.net.parameters(), again.net.parameters(), strict=True):
        assert torch.allclose(p, q, atol=1e-6, rtol=0)


def test_epochs_roll_over(cache_dir: Path, tmp_path: Path) -> None:
    stream = ClipStream(cache_dir, "train", "geom_only", seed=1)
    n_batches = -(-len(stream.clips) // 8)
    tr = Trainer(tiny_net(), TrainConfig(lr=1e-3))
    train_loop(tr, stream, n_batches + 1, 8, ckpt_dir=tmp_path / "ck")
    assert resume(tmp_path / "ck").extra["stream"]["epoch"] == 1
    assert tr.step_count == n_batches + 1


class _NanAtStep3(Trainer):
    """A trainer whose loss turns NaN at update 3 (as a diverging run's would)."""

    def loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        loss = super().loss(batch)
        return loss * float("nan") if self.step_count == 3 else loss


def _files(ck: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(ck.iterdir())}


def test_nan_loss_stops_with_step_last_loss_and_checkpoint(cache_dir: Path,
                                                           tmp_path: Path) -> None:
    ck = tmp_path / "ck"
    tr = _NanAtStep3(tiny_net(), TrainConfig(lr=1e-3, seed=3))
    seen: list[float] = []
    with pytest.raises(TrainingDiverged) as info:
        train_loop(tr, ClipStream(cache_dir, "train", "geom_only", seed=1), 8, 2,
                   ckpt_dir=ck, every=2, on_step=lambda s, loss: seen.append(loss))
    err = info.value
    assert err.step == 3 and err.checkpoint == ck and err.last_loss == seen[-1]
    assert "step 3" in str(err) and str(ck) in str(err) and "(step 2)" in str(err)
    saved = _files(ck)
    assert read_meta(ck)["step"] == 2  # the last good save, untouched
    assert tr.step_count == 3 and all(torch.isfinite(p).all() for p in tr.net.parameters())
    resumed = resume(ck)
    assert resumed.step_count == 2 and _files(ck) == saved


def test_non_finite_gradient_stops_before_the_update(cache_dir: Path, tmp_path: Path) -> None:
    tr = Trainer(tiny_net(), TrainConfig(lr=1e-3, seed=3))
    first = next(tr.net.parameters())
    first.register_hook(lambda g: g * float("inf") if tr.step_count == 1 else g)
    with pytest.raises(TrainingDiverged) as info:
        train_loop(tr, ClipStream(cache_dir, "train", "geom_only", seed=1), 4, 2)
    assert info.value.step == 1 and info.value.checkpoint is None
    assert "gradient" in str(info.value) and "no checkpoint" in str(info.value)
    assert all(torch.isfinite(p).all() for p in tr.net.parameters())  # never applied


def test_save_refuses_non_finite_weights(tmp_path: Path) -> None:
    tr = Trainer(tiny_net(), TrainConfig(lr=1e-3))
    tr.save(tmp_path / "ck")
    before = _files(tmp_path / "ck")
    with torch.no_grad():
        next(tr.net.parameters()).fill_(float("nan"))
    with pytest.raises(DivergedError):
        tr.save(tmp_path / "ck")
    assert _files(tmp_path / "ck") == before


def test_nan_latents_with_valid_checksums_name_the_input_at_step_0(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    """A producer that wrote NaN latents (the chunk CRCs match: the bytes are as written):
    training stops before the first update naming the input, not the learning rate."""
    import zarr

    from model.loop import NonFiniteInput
    from tests.model.cache_fixture import build_cache, random_fill

    out = tmp_path_factory.mktemp("nan_cache")
    build_cache(out, fill=random_fill)  # m3gd's own writer refuses NaN: zarr-python writes it
    zarr.open_array(str(out / "cache.zarr" / "r0" / "left" / "latents_l0"),
                    mode="r+")[5, 0, 1, 2] = np.nan
    stream = ClipStream(out, "train", "geom_only", seed=1)
    tr = Trainer(tiny_net(), TrainConfig(lr=1e-3, seed=3))
    with pytest.raises(NonFiniteInput) as info:
        train_loop(tr, stream, 2, len(stream.clips))  # one batch: every train clip
    text = str(info.value)
    assert "\n" not in text and "step 0" in text and "learning rate" not in text
    assert "latents (cache array latents_l0) of r0/left views [2, 3, 4, 5], r0/left views " \
           "[4, 5, 6, 7]" in text, text
    assert "r0/front" not in text and "r1/" not in text
    assert tr.step_count == 0 and all(torch.isfinite(p).all() for p in tr.net.parameters())
