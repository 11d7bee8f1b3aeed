"""The loader bench's warp cost: device path against host path, both timed in one run."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import model.adapter as adapter
from bench.loader_bench import LoaderBenchSpec, warp_cost, warp_path
from model.warp_device import warp_channels_device
from schemas.cache_layout import GridSpec
from tests.model.cache_fixture import build_cache, random_fill, stamp_encoders
from tests.model.model_fixtures import IMAGE, make_batch


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A random cache on a 4 x 6 grid (the tiny preset's patch 2 divides it) with the encoder
    identities the encode stage writes."""
    out = tmp_path_factory.mktemp("cache")
    build_cache(out, grid=GridSpec(56, 84), fill=random_fill)
    stamp_encoders(out)
    return out


def test_warp_cost_reports_both_paths_against_no_lidar(cache_dir: Path) -> None:
    torch.set_num_threads(1)
    out = warp_cost(cache_dir, LoaderBenchSpec(batch_size=2, model_steps=2))
    for k in ("no_lidar", "warp", "warp_host_path"):
        assert out[f"s_per_step_{k}"] > 0
    assert 0 < out["s_warp_channels"] < out["s_per_step_warp"]
    assert 0 < out["s_warp_channels_host_path"] < out["s_per_step_warp_host_path"]
    base = out["s_per_step_no_lidar"]
    assert out["warp_host_cost_over_no_lidar"] == pytest.approx(
        (base + out["s_warp_channels"]) / base)
    assert out["warp_host_cost_over_no_lidar_host_path"] == pytest.approx(
        (base + out["s_warp_channels_host_path"]) / base)
    assert out["warp_step_over_no_lidar"] == pytest.approx(out["s_per_step_warp"] / base)


def test_the_chosen_path_is_swapped_in_only_within_the_block() -> None:
    before = adapter.warp_channels
    spent: list[float] = []
    b = make_batch()
    args = (b["latents"], b["g"], b["K"], b["T_world_cam"], b["is_target"], IMAGE)
    for host, want in ((True, adapter.warp_channels_host), (False, warp_channels_device)):
        with warp_path(host, spent):
            assert torch.equal(adapter.warp_channels(*args), want(*args))
        assert adapter.warp_channels is before
    assert len(spent) == 2 and min(spent) > 0
    with pytest.raises(RuntimeError), warp_path(True, spent):
        raise RuntimeError
    assert adapter.warp_channels is before
