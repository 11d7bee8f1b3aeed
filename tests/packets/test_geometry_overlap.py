"""Cross-view consistency (`packets.view_overlap`) and how it enters the geometry verdict: views
that agree keep an `ok`; views that disagree fail it (pose source); no overlap leaves it
`inconclusive` saying so; a searched geometry that scores clearly higher is never `ok`."""

from __future__ import annotations

import numpy as np
import pytest

from packets.geometry_verdict import (
    FAILED,
    INCONCLUSIVE,
    OK,
    POSE_CAUSE,
    Evidence,
    NullTest,
    Search,
    decide,
)
from packets.view_overlap import CrossView, cross_view, near_pairs, overlap_min_points

GOOD = NullTest(0.5, 0.05, 0.02, 0.0005, 22.5, 0.95, 24)
EV = Evidence(24, 5000, 0, "", 0.35)


def test_near_pairs_are_both_directions_within_the_lag() -> None:
    pairs = near_pairs(4, 2)
    assert {tuple(p) for p in pairs} == {(0, 1), (0, 2), (1, 0), (1, 2), (1, 3), (2, 0),
                                         (2, 1), (2, 3), (3, 1), (3, 2)}
    assert near_pairs(1).shape == (0, 2)


def test_cross_view_uses_only_overlapping_pairs() -> None:
    cv = cross_view([0.4, 0.9, 0.0], [100, 10, 60], [0.5, 0.5, 0.6], 0.05, 0.02, min_points=50)
    assert cv.pairs == 2 and cv.points == 160 and not cv.problem
    assert cv.score == pytest.approx(0.2) and cv.own == pytest.approx(0.55)
    assert cv.z == pytest.approx((0.2 - 0.05) / 0.02)


def test_no_overlap_says_so() -> None:
    cv = cross_view([0.4, 0.9], [3, 10], [0.5, 0.5], 0.05, 0.02, min_points=50)
    assert cv.pairs == 0 and cv.problem.startswith("no overlap") and "at most 10" in cv.problem
    with pytest.raises(ValueError, match="one \\(P,\\)"):
        cross_view([0.1], [1, 2], [0.1], 0.0, 1.0)


def _cross(score: float, own: float = 0.5, pairs: int = 40, problem: str = "") -> CrossView:
    return CrossView(pairs, pairs, 100 * pairs, score, own, (score - 0.05) / 0.02, problem)


def test_agreeing_views_keep_ok_and_disagreeing_ones_fail_naming_the_pose_source() -> None:
    assert decide(GOOD, EV, cross=_cross(0.49)).verdict == OK
    v = decide(GOOD, EV, cross=_cross(0.04))
    assert v.verdict == FAILED and v.cause == POSE_CAUSE and "disagree" in v.reason
    # too few overlapping pairs to blame the odometry: ok on the own score alone
    assert decide(GOOD, EV, cross=_cross(0.04, pairs=3)).verdict == OK


def test_no_overlap_turns_ok_into_inconclusive() -> None:
    v = decide(GOOD, EV, cross=_cross(0.0, pairs=0, problem="no overlap: none"))
    assert v.verdict == INCONCLUSIVE and "cross-view: inconclusive: no overlap" in v.reason


def test_a_searched_geometry_scoring_clearly_higher_is_never_ok() -> None:
    near = Search(0.6, 27.5, "clock offset (+50 ms)")  # 0.5 < 0.9 x 0.6, not < 0.75 x 0.6
    v = decide(GOOD, EV, near)
    assert v.verdict == INCONCLUSIVE and v.cause == near.moved and "scores higher" in v.reason
    assert decide(GOOD, EV, Search(0.52, 23.5, "x")).verdict == OK
    assert decide(GOOD, EV, Search(0.8, 37.5, "yaw")).verdict == FAILED
    assert np.isfinite(GOOD.z)


def test_overlap_needs_fewer_points_of_a_sparse_scan() -> None:
    assert overlap_min_points([400, 500, 300]) == 50  # dense: MIN_POINTS
    assert overlap_min_points([14, 16, 12]) == 7  # sparse: half the median
    assert overlap_min_points([2, 3]) == 5 and overlap_min_points([]) == 5
