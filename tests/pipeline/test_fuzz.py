"""Fuzzing ingest with damaged bags (hypothesis, seeded): the contract holds in every case.

The short run (8 cases) is in the default suite; the long one (200 cases) is marked slow.
Invariants: no crash (a refusal is a one-line ValueError naming the bag or topic), the
accounting holds, no message is lost silently, no NaN/Inf reaches the index or the cache, and
where no byte of a message changed (truncation, chunk swaps) nothing differs from the clean
twin. Byte flips inside an image's or a sweep's payload that decode without error cannot be
detected (a ROS1 bag has no checksum); `m3gd bench fuzz` counts them (damaged_views_cached).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.bench.fuzz import BAGS, CaseResult, Twin, make_base, run_case, run_fuzz
from pipeline.bench.fuzz_cases import MUTATIONS


@pytest.fixture(scope="module")
def twin(tmp_path_factory: pytest.TempPathFactory) -> Twin:
    work = tmp_path_factory.mktemp("fuzz")
    return Twin.of(make_base(work / "base_root"), work)


def _check(r: CaseResult) -> None:
    where = f"{r.bag} {r.mutation} seed {r.seed}: {r.what}"
    assert not r.crash, f"{where}: {r.crash}"
    if r.refused:
        assert "\n" not in r.refused and (".bag" in r.refused or "/" in r.refused), where
        return
    assert r.accounting_gaps == 0 and r.silent_losses == 0 and r.nonfinite == 0, where
    if r.mutation in ("truncate", "shuffle"):  # no byte of any message was changed
        assert r.damaged_images == r.damaged_sweeps == r.damaged_poses == 0, where


CASE = {"bag": st.sampled_from(BAGS), "mutation": st.sampled_from(sorted(MUTATIONS)),
        "seed": st.integers(0, 2**31 - 1)}  # fmt: skip


def _fuzz(examples: int) -> Callable[..., None]:
    """A seeded fuzz test of `examples` cases (hypothesis, derandomized)."""

    @settings(max_examples=examples, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
    @given(**CASE)
    def fuzz(twin: Twin, tmp_path_factory: pytest.TempPathFactory, bag: str, mutation: str,
             seed: int) -> None:  # fmt: skip
        _check(run_case(twin, bag, mutation, seed, tmp_path_factory.getbasetemp() / "cases"))

    return fuzz


test_fuzz_short = _fuzz(8)
test_fuzz_long = pytest.mark.slow(_fuzz(200))


def test_first_chunk_flip_of_each_sensor(twin: Twin, tmp_path: Path) -> None:
    """The audit's case for every bag: 30 bytes flipped inside the first chunk."""
    results = [run_case(twin, bag, "flip_first_chunk", 7, tmp_path) for bag in BAGS]
    assert [r.bag for r in results] == list(BAGS)
    for r in results:
        _check(r)
        # the audit's loss: a damaged first chunk must not lose the bag's messages silently
        assert not r.crash and r.silent_losses == 0 and r.accounting_gaps == 0, r


def test_bench_figures(tmp_path: Path) -> None:
    figures = run_fuzz(tmp_path, max_cases=4, seconds=60, lock_trials=1, lock_starts=3)
    assert figures["cases_tried"] == 4 and figures["lock_starts"] == 6
    for key in ("crashes", "silent_losses", "accounting_gaps", "lock_double_holds",
                "nonfinite_values"):
        assert figures[key] == 0, (key, figures)
    assert {"damaged_views_cached", "damaged_sweeps_indexed", "refused_in_one_line"} <= set(figures)
