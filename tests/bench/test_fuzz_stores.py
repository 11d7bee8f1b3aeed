"""The store fuzz cases: damaged HF chunks never crash ingest; flipped cache bits are never
read back silently, and `verify_cache` finds every flipped chunk."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.fuzz_stores import damage_chunk, run_cache_flips, run_hf_cases


def test_cache_flips_are_never_silent(tmp_path: Path) -> None:
    figures = run_cache_flips(tmp_path, 25, seed=3)
    assert figures["silent_cache_corruptions"] == 0, figures
    assert figures["cache_flips_missed_by_verify"] == 0


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
