"""packets.items auto: LPT makespan, which recordings are split, order of the items."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.stages.packets_plan import choose_units, makespan


def test_makespan_is_the_lpt_schedule() -> None:
    assert makespan([5, 4, 3, 3, 3], 2) == 10  # LPT: 5+3 | 4+3+3 (the optimum is 9)
    assert makespan([7], 4) == 7
    assert makespan([], 2) == 0
    assert makespan([1, 1, 1, 1], 1) == 4


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.1, 100), min_size=1, max_size=6), st.integers(1, 4))
def test_makespan_bounds(costs: list[float], workers: int) -> None:
    span = makespan(costs, workers)
    lower = max(max(costs), sum(costs) / workers)
    best = min(max(sum(c for c, w in zip(costs, assign, strict=True) if w == k)
                   for k in range(workers))
               for assign in itertools.product(range(workers), repeat=len(costs)))
    assert lower - 1e-9 <= best <= span + 1e-9  # summed in other orders: round-off
    assert span <= best * (4 / 3) + 1e-9  # Graham's LPT bound


def test_one_worker_never_splits() -> None:
    units = choose_units({"a": 10.0, "b": 1.0}, {"a": [4.0, 4.0, 4.0], "b": [1.0]}, 1)
    assert [u.key for u in units] == ["a", "b"]


def test_balanced_recordings_stay_whole_costliest_first() -> None:
    whole = {"a": 3.0, "b": 5.0, "c": 4.0, "d": 4.0}
    rows = {r: [c / 2 + 0.1, c / 2 + 0.1] for r, c in whole.items()}
    units = choose_units(whole, rows, 2)
    assert [u.key for u in units] == ["b", "c", "d", "a"]  # LPT: b+a | c+d = 8 | 8


def test_one_long_recording_is_split_into_rows() -> None:
    whole = {"long": 12.0, "short": 2.0}
    rows = {"long": [4.2, 4.2, 4.2], "short": [2.0]}
    units = choose_units(whole, rows, 2)
    assert sorted(u.key for u in units) == ["long/0", "long/1", "long/2", "short"]
    assert makespan([u.cost for u in units], 2) < 12.0


def test_equal_recordings_split_together_when_workers_outnumber_them() -> None:
    whole = {"a": 10.0, "b": 10.0}
    rows = {"a": [3.5, 3.5, 3.5], "b": [3.5, 3.5, 3.5]}  # splitting one alone gains nothing
    units = choose_units(whole, rows, 3)
    assert len(units) == 6 and makespan([u.cost for u in units], 3) == 7.0


def test_split_refused_when_rows_cost_more_than_they_save() -> None:
    whole = {"a": 10.0, "b": 10.0}
    rows = {"a": [6.0, 6.0], "b": [6.0, 6.0]}  # shared sweeps: 12 > 10 split
    assert sorted(u.key for u in choose_units(whole, rows, 2)) == ["a", "b"]


@pytest.mark.parametrize("workers", [2, 3, 4])
def test_every_recording_covered_once(workers: int) -> None:
    whole = {"a": 9.0, "b": 3.0, "c": 1.0}
    rows = {"a": [3.1, 3.1, 3.1], "b": [1.6, 1.6], "c": []}
    units = choose_units(whole, rows, workers)
    for rec in whole:
        mine = sorted(u.row for u in units if u.recording == rec if u.row is not None)
        whole_units = [u for u in units if u.recording == rec and u.row is None]
        assert (len(whole_units), mine) in ((1, []), (0, list(range(len(rows[rec])))))
    costs = [u.cost for u in units]
    assert costs == sorted(costs, reverse=True)
