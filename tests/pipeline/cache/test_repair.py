"""Repairs are loops: a damaged chunk of any array kind, `verify`, a rerun -> byte-identical to
the clean run, no array lost, verify clean (one tiny recording run once; each case on a copy).

Was: a flipped bit in `images` made verify forget ingest only; the rerun re-ingested (which
rewrites the camera's group from scratch) and reported every later stage up to date, so the
group kept only images, K and stamp_ns, and verify then said "none corrupt".
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.fuzz_repair import (
    array_kinds,
    arrays_of,
    digests,
    make_recording,
    raw_config,
    repair_round,
    run_all,
    verify,
)
from schemas.config import parse_config


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """The clean output of the tiny recording and its raw config."""
    base = tmp_path_factory.mktemp("repair")
    raw = raw_config(base / "clean", make_recording(base / "recordings"))
    assert run_all(parse_config(raw)) == []
    return base / "clean", raw


def test_the_clean_run_holds_every_array_kind_and_verifies(
        clean: tuple[Path, dict[str, Any]]) -> None:
    out, _ = clean
    assert {a.split("/")[-1] for a in arrays_of(out)} == set(array_kinds())
    report, forgotten = verify(out)
    assert not report.damaged and forgotten == [] and report.checked > 0


def check_repair(clean: tuple[Path, dict[str, Any]], case: Path, array: str, pick: int) -> None:
    out, raw = clean
    before = digests(out)
    r = repair_round(out, case, raw, array, pick)
    assert r.detected, r  # verify named the flipped chunk
    assert r.failed == [] and r.lost == [] and r.not_identical == [], r
    assert not r.still_damaged, r
    assert digests(out) == before  # the clean output itself was not touched
    shutil.rmtree(case)


@pytest.mark.parametrize("array", array_kinds())
def test_damage_verify_rerun_is_byte_identical(clean: tuple[Path, dict[str, Any]],
                                               tmp_path: Path, array: str) -> None:
    """Every array kind, one stored chunk each (a different one per kind)."""
    check_repair(clean, tmp_path / "case", array, 7 * array_kinds().index(array) + 1)


@pytest.mark.slow
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(array=st.sampled_from(array_kinds()), pick=st.integers(0, 2**31 - 1))
def test_any_damaged_chunk_of_any_array_repairs(clean: tuple[Path, dict[str, Any]],
                                                tmp_path: Path, array: str,
                                                pick: int) -> None:
    check_repair(clean, tmp_path / "case", array, pick)
