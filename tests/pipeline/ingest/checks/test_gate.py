"""Stamp gate: accepted stamps strictly increase; swaps, duplicates and gaps are named."""

from __future__ import annotations

import itertools

from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.checks.gate import TopicGate, Verdict


def _run(stamps: list[int]) -> list[Verdict]:
    gate = TopicGate()
    out: list[Verdict] = []
    for i, s in enumerate(stamps):
        for v in gate.push(s, i):
            out.append(v)
            if v.reason is None:
                gate.accepted(v.stamp_ns)
    out += gate.flush()
    return out


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(0, 50), max_size=40))
def test_accepted_stamps_strictly_increase(stamps: list[int]) -> None:
    verdicts = _run(stamps)
    assert [v.item for v in verdicts] == list(range(len(stamps)))  # every message judged once
    ok = [v.stamp_ns for v in verdicts if v.reason is None]
    assert all(a < b for a, b in itertools.pairwise(ok))


def test_swap_refuses_both_and_duplicate_keeps_the_first() -> None:
    stamps = [0, 100, 300, 200, 400, 400, 500]
    reasons = [v.reason.value if v.reason else "" for v in _run(stamps)]
    assert reasons == ["", "", "out_of_order_stamp", "out_of_order_stamp", "", "duplicate_stamp",
                       ""]  # fmt: skip


def test_a_resent_message_is_a_duplicate_and_costs_no_neighbour() -> None:
    """A sweep duplicated later in the stream: only the copy is refused (was: its neighbour too)."""
    stamps = [0, 100, 200, 100, 300, 400, 300, 500]
    reasons = [v.reason.value if v.reason else "" for v in _run(stamps)]
    assert reasons == ["", "", "", "duplicate_stamp", "", "", "duplicate_stamp", ""]


def test_gap_is_recorded_once() -> None:
    gate = TopicGate()
    for s in [*range(0, 1000, 100), 2000, 2100]:
        for v in gate.push(s, s):
            gate.accepted(v.stamp_ns)
    assert [(g.before_ns, g.after_ns, g.median_step_ns) for g in gate.gaps] == [(900, 2000, 100)]
