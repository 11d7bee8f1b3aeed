"""The writer A/B bench: an earlier revision's writer stands in only inside its block."""

from __future__ import annotations

from pathlib import Path

import store.cache_store as cache_store
from bench.cache_data import CacheBenchSpec
from bench.cache_write_ab import run_writer_ab, writer_at, writing_with
from store import shard_writer

TINY = CacheBenchSpec(views=16, channels=32, point_channels=16, shard_views=8)


def test_baseline_writer_stands_in_inside_the_block_only() -> None:
    baseline = writer_at("HEAD")
    assert baseline.__name__ == "baseline_shard_writer"
    with writing_with(baseline):
        assert cache_store.write_raw is baseline.write_raw
    assert cache_store.write_raw is shard_writer.write_raw


def test_figures_for_both_writers(tmp_path: Path) -> None:
    out = run_writer_ab("HEAD", 3, TINY, tmp_path)
    for who in ("before", "after"):
        assert out[f"{who}_rounds"] == 3
        assert out[f"{who}_vs_npy_paired_min"] <= out[f"{who}_vs_npy_paired_max"]
        assert out[f"{who}_store_cpu_s_median"] > 0
    assert out["before_npy_wall_s_median"] == out["after_npy_wall_s_median"]  # one .npy
    assert list(tmp_path.iterdir()) == []
