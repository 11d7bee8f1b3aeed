"""Cache benchmark on a tiny size: every figure present, the structural ones as expected."""

from __future__ import annotations

from pathlib import Path

from bench.cache_bench import run_cache_bench
from bench.cache_data import CacheBenchSpec


def test_tiny_cache_bench(tmp_path: Path) -> None:
    spec = CacheBenchSpec(views=16, channels=32, point_channels=16, shard_views=8, clips=10,
                          clip_span=8)
    out = run_cache_bench(spec, tmp_path, repeats=2)
    assert out["files_ratio"] > 1  # 48 .npy files against a handful of shards and metadata
    assert 0 < out["packet_bytes_ratio"] < 1  # mostly empty cells compress
    assert 0.99 < out["latent_bytes_ratio"] < 1.01  # dense float16, stored raw
    assert out["write_vs_npy_per_view"] > 0 and out["clip_read_vs_npy_per_view"] > 0
    assert 0 < out["fp16_max_rel_error"] < 1e-3
    # one reader for the run: the first clip opens 3 zarr.json and its shard files, later
    # clips (8 views per shard, all within 2 shards) only the shards not yet open
    assert out["files_opened_first_clip"] == 3 + out["shard_files_touched_first_clip"]
    assert out["files_opened_per_clip"] <= (3 + 6) / 10
    assert out["clip_read_over_floor_warm"] > 0 and out["clip_read_over_floor_cold"] > 0
    assert out["clip_read_over_floor_warm_unchecked"] > 0  # the same reader, CRC32C unchecked
    assert out["clip_read_over_floor_warm_verify_always"] > 0
    assert out["crc_check_cost_warm"] > -1 and out["crc_check_always_cost_warm"] > -1
    assert out["checksummed_read_cost_warm"] > -1  # against format 2's layout, same values
    assert 0.49 < out["fp16_size_ratio"] < 0.51  # measured on disk (shard index included)
    parts = ["pack", "finite", "crc32c", "writev", "setup"]
    assert all(out[f"write_part_cpu_s_{p}"] >= 0 for p in parts)
    assert out["write_parts_cpu_s_sum"] == sum(out[f"write_part_cpu_s_{p}"] for p in parts)
    assert out["write_rounds"] == 7 and out["write_vs_npy_paired_min"] <= (
        out["write_vs_npy_paired_max"])
    assert list(tmp_path.iterdir()) == []  # the benchmark cleans up after itself
