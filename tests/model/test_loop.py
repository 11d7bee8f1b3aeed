"""Training loop on a tiny cache: runs through the stream, resumes mid-epoch exactly."""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest
import torch

from model.dataset import ClipStream
from model.loop import resume, train_loop
from model.net import NetConfig
from model.train_step import TrainConfig, Trainer
from tests.model.cache_fixture import CU, GRID, C, build_cache


def _fill(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
    rng = np.random.default_rng(zlib.crc32(f"{rec}/{cam}".encode()))
    arrays["K"][:] = [[20.0, 0, 20.5], [0, 20.0, 13.5], [0, 0, 1]]
    arrays["latents_l0"][:] = rng.standard_normal(arrays["latents_l0"].shape)
    arrays["g"][:] = rng.random(arrays["g"].shape)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cache")
    build_cache(out, fill=_fill)
    return out


def _cfg() -> NetConfig:
    return NetConfig(c=C, c_u=CU, grid_hw=(GRID.grid_h, GRID.grid_w),
                     image_hw=(GRID.image_h, GRID.image_w), mode="geom_only", patch=1,
                     adapter_hidden=16)


def test_resume_mid_epoch_equals_straight(cache_dir: Path, tmp_path: Path) -> None:
    tcfg = TrainConfig(lr=1e-3, seed=3)
    straight = Trainer(_cfg(), tcfg)
    losses = train_loop(straight, ClipStream(cache_dir, "train", "geom_only", seed=1), 5, 2)
    assert len(losses) == 5 and all(np.isfinite(losses))
    first = Trainer(_cfg(), tcfg)
    train_loop(first, ClipStream(cache_dir, "train", "geom_only", seed=1), 3, 2,
               ckpt_dir=tmp_path / "ck")
    stream = ClipStream(cache_dir, "train", "geom_only", seed=1)
    again = resume(tmp_path / "ck", stream)
    assert stream.state.consumed  # moved past the first 3 batches
    rest = train_loop(again, stream, 5, 2)
    assert rest == pytest.approx(losses[3:], abs=1e-6)
    for p, q in zip(straight.net.parameters(), again.net.parameters(), strict=True):
        assert torch.allclose(p, q, atol=1e-6, rtol=0)


def test_epochs_roll_over(cache_dir: Path) -> None:
    stream = ClipStream(cache_dir, "train", "geom_only", seed=1)
    n_batches = -(-len(stream.clips) // 8)
    tr = Trainer(_cfg(), TrainConfig(lr=1e-3))
    train_loop(tr, stream, n_batches + 1, 8)
    assert stream.state.epoch == 1 and tr.step_count == n_batches + 1
