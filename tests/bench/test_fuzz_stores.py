"""The store fuzz cases: damaged HF chunks never crash ingest; flipped cache bits are never
read back silently, and `verify_cache` finds every flipped chunk."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.fuzz_stores import _in_stored_chunks, damage_chunk, run_cache_flips, run_hf_cases
from store.raw_shard import shard_index


def test_cache_flips_are_never_silent(tmp_path: Path) -> None:
    figures = run_cache_flips(tmp_path, 25, seed=3)
    assert figures["silent_cache_corruptions"] == 0, figures
    assert figures["cache_flips_missed_by_verify"] == 0


def test_a_flip_counts_as_damage_only_inside_a_stored_chunk() -> None:
    """Chunks of 100 bytes at 0 and 128 (chunk 2 missing): bytes 100-127 are padding;
    both ends of each chunk are pinned (start inclusive, end exclusive)."""
    index = shard_index([True, True, False], 100)
    assert _in_stored_chunks(index, [0]) and _in_stored_chunks(index, [99])
    assert not _in_stored_chunks(index, [100]) and not _in_stored_chunks(index, [127])
    assert _in_stored_chunks(index, [128]) and _in_stored_chunks(index, [227])
    assert not _in_stored_chunks(index, [228, 110])
    assert _in_stored_chunks(index, [110, 150])  # any one inside is damage


def test_hf_cases_never_crash(tmp_path: Path) -> None:
    figures = run_hf_cases(tmp_path, 3, 300.0, seed=5)
    assert figures["hf_cases"] == 3 and figures["hf_crashes"] == 0, figures
    assert figures["hf_rows_gained"] == 0 and figures["hf_accounting_gaps"] == 0


def test_damage_chunk_cuts_or_flips(tmp_path: Path) -> None:
    path = tmp_path / "c"
    seen = set()
    for seed in range(8):
        path.write_bytes(bytes(range(256)) * 4)
        what = damage_chunk(path, np.random.default_rng(seed))
        seen.add(what.split()[0] == "cut")
        data = path.read_bytes()
        assert (len(data) < 1024) if what.startswith("cut") else (
            len(data) == 1024 and data != bytes(range(256)) * 4)
    assert seen == {True, False}
