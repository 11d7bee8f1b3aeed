"""The pieces of `m3gd bench ddp` that run without torchrun: the deal, the kill windows."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from bench.ddp_bench import deal, kill_windows, m3gd, max_abs_diff
from model.net import NetConfig
from tests.model.cache_fixture import build_cache


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cache")
    build_cache(out)
    return out


def test_deal_reads_each_clip_once_on_disjoint_ranks(cache_dir: Path) -> None:
    assert deal(cache_dir, "geom_only", 3, ranks=2, workers=0) == {
        "clips_seen_once": True, "ranks_disjoint": True}


def test_every_kill_window_is_safe(cache_dir: Path, tmp_path: Path) -> None:
    cfg = NetConfig(c=4, c_u=3, grid_hw=(2, 4), image_hw=(28, 56), mode="geom_only",
                    adapter_hidden=8)
    res = kill_windows(tmp_path, cfg)
    assert res == {"checkpoint_kill_windows": 8, "checkpoint_kill_windows_unsafe": 0}


def test_max_abs_diff_and_command_lines() -> None:
    a = {"w": torch.zeros(3)}
    assert max_abs_diff(a, {"w": torch.tensor([0.0, -2e-4, 1e-5])}) == pytest.approx(2e-4)
    with pytest.raises(ValueError):
        max_abs_diff(a, {"v": torch.zeros(3)})
    assert m3gd(["train"], 2)[1:5] == ["-m", "torch.distributed.run", "--standalone",
                                       "--nproc-per-node=2"]
