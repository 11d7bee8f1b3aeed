"""Science-check runner on a tiny cache whose latents are exact patch encodings of its images."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from model.compare import CompareSpec, net_config_from_cache, train_and_score
from model.dataset import ClipStream
from model.encoders.patch import PatchEncoder
from model.net import NetConfig
from model.train_step import TrainConfig
from tests.model.cache_fixture import CU, GRID, build_cache, stamp_encoders

C = 588  # exact patch decoder


def _fill(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
    rng = np.random.default_rng(len(rec) * 7 + len(cam))
    n = arrays["images"].shape[0]
    base = rng.integers(0, 256, (1, *arrays["images"].shape[1:]))
    drift = np.arange(n)[:, None, None, None] * 3  # frames brighten slowly
    arrays["images"][:] = np.clip(base + drift, 0, 255).astype(np.uint8)
    arrays["latents_l0"][:] = PatchEncoder(C).encode(arrays["images"])[0]
    arrays["K"][:] = [[20.0, 0, 20.5], [0, 20.0, 13.5], [0, 0, 1]]
    arrays["g"][:] = rng.random(arrays["g"].shape)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cache")
    build_cache(out, channels=(C, CU), fill=_fill)
    return out


def _run(cache_dir: Path, mode: str, spec: CompareSpec) -> dict[str, Any]:
    cfg = NetConfig(c=C, c_u=CU, grid_hw=(GRID.grid_h, GRID.grid_w),
                    image_hw=(GRID.image_h, GRID.image_w), mode=mode, patch=1,
                    adapter_hidden=16)
    return train_and_score(cache_dir, mode, PatchEncoder(C), spec, TrainConfig(lr=1e-3), cfg)


def test_train_and_score_runs_both_modes(cache_dir: Path) -> None:
    spec = CompareSpec(steps=3, batch_size=4, eval_clips=4, sample_steps=2)
    out = {mode: _run(cache_dir, mode, spec) for mode in ("full", "no_lidar")}
    for mode, r in out.items():
        assert r["mode"] == mode and r["steps"] == 3
        # one eval batch of 4 clips, 2 targets each (the fixture's [F, T, F, T] roles)
        assert r["eval_clips"] == 4 and r["eval_targets"] == 8
        assert math.isfinite(r["psnr_mean"]) and 0 < r["psnr_mean"] < 40
        assert math.isfinite(r["psnr_median"]) and -1 <= r["ssim_mean"] <= 1
        assert math.isfinite(r["final_loss"]) and r["final_loss"] > 0
    # the two modes are really different models: their numbers differ
    full, no_lidar = out["full"], out["no_lidar"]
    assert full["final_loss"] != no_lidar["final_loss"]
    assert full["psnr_mean"] != no_lidar["psnr_mean"]
    # same seed, same data order and budget: a rerun repeats every number exactly
    assert _run(cache_dir, "full", spec) == full


def test_net_config_from_cache_reads_encoder_identities(cache_dir: Path) -> None:
    stamp_encoders(cache_dir, c=C)
    cfg = net_config_from_cache(ClipStream(cache_dir, "train", "full"), "full", "tiny")
    assert (cfg.c, cfg.c_u, cfg.grid_hw) == (C, CU, (GRID.grid_h, GRID.grid_w))
    assert cfg.image_hw == (GRID.image_h, GRID.image_w) and cfg.mode == "full"
