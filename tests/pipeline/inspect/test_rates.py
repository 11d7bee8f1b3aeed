"""Rates and gaps from message times, boundaries pinned."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.inspect.rates import GAP_FACTOR, MAX_GAPS, NS, timing

T0 = 1_700_000_000_000_000_000


def test_regular_stream() -> None:
    t = timing(T0 + np.arange(11) * NS // 10)
    assert t.rate_hz == pytest.approx(10.0) and t.period_s == pytest.approx(0.1)
    assert t.n_gaps == 0 and t.first_ns == T0 and t.last_ns == T0 + NS


def test_gap_found_longest_first_and_unsorted_input() -> None:
    times = list(T0 + np.arange(40) * 100_000_000)
    times = [x for i, x in enumerate(times) if not (5 <= i < 8) and not (20 <= i < 30)]
    t = timing(times[::-1])
    assert t.n_gaps == 2
    assert [round(g.seconds, 6) for g in t.gaps] == [1.1, 0.4]
    assert t.gaps[0].start_ns == T0 + 19 * 100_000_000


def test_gap_boundary_is_exclusive() -> None:
    period = 100_000_000
    base = list(T0 + np.arange(10) * period)
    at = timing([*base, base[-1] + int(GAP_FACTOR * period)])
    over = timing([*base, base[-1] + int(GAP_FACTOR * period) + 1])
    assert at.n_gaps == 0 and over.n_gaps == 1


def test_empty_single_and_burst() -> None:
    assert timing([]).first_ns is None
    one = timing([T0])
    assert one.first_ns == one.last_ns == T0 and one.rate_hz is None
    same = timing([T0, T0, T0])
    assert same.rate_hz is None and same.n_gaps == 0
    burst = timing([T0, T0, T0, T0 + NS])  # median interval 0: no gap can be measured
    assert burst.period_s == 0.0 and burst.n_gaps == 0


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 2**62), min_size=2, max_size=200))
def test_gaps_at_extremes(times: list[int]) -> None:
    t = timing(times)
    assert t.first_ns == min(times) and t.last_ns == max(times)
    assert len(t.gaps) == min(t.n_gaps, MAX_GAPS)
    assert all(a.seconds >= b.seconds for a, b in zip(t.gaps, t.gaps[1:], strict=False))
