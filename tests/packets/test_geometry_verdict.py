"""The shuffled-pairs null and the verdict on hand-built score matrices: exact moments, the
tail probability's ties, the z of a null without spread, the verdict's boundaries (inclusive
where the docstring says >=, exclusive where <), and thin evidence never `failed`."""

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
    Thresholds,
    decide,
    null_draws,
    null_moments,
    null_rows,
    null_test,
    tail_p,
    win_share,
    z_score,
)

AMPLE = Evidence(views=24, points=5000)


def test_null_rows_need_min_pairs_and_never_count_the_diagonal() -> None:
    allowed = np.ones((4, 4), bool)  # the diagonal set too: it must not count
    allowed[0] = [True, False, False, True]  # row 0: only column 3 off the diagonal
    assert null_rows(allowed, 3).tolist() == [1, 2, 3]
    assert null_rows(allowed, 1).tolist() == [0, 1, 2, 3]
    assert null_rows(allowed, 4).tolist() == []


def test_null_moments_are_exact_on_a_hand_built_matrix() -> None:
    S = np.array([[9.0, 1.0, 3.0], [2.0, 9.0, 4.0], [0.0, 6.0, 9.0]])
    allowed = np.ones((3, 3), bool)
    mean, std = null_moments(S, allowed, np.arange(3))
    # row means 2, 3, 3; row population variances 1, 1, 9
    assert mean == pytest.approx(8 / 3)
    assert std == pytest.approx(np.sqrt(11) / 3)
    draws = null_draws(S, allowed, np.arange(3), 20000, seed=1)
    assert draws.mean() == pytest.approx(mean, abs=0.02)
    assert draws.std() == pytest.approx(std, rel=0.03)
    assert set(np.round(draws * 3).astype(int)) <= {1 + 2 + 0, 1 + 2 + 6, 1 + 4 + 0, 1 + 4 + 6,
                                                   3 + 2 + 0, 3 + 2 + 6, 3 + 4 + 0, 3 + 4 + 6}


def test_tail_p_counts_ties_against_the_observed_value() -> None:
    null = np.array([0.1, 0.2, 0.3])
    assert tail_p(0.3, null) == pytest.approx(2 / 4)  # the tie counts
    assert tail_p(0.30000001, null) == pytest.approx(1 / 4)
    assert tail_p(-1.0, null) == 1.0
    assert tail_p(5.0, np.zeros(0)) == 1.0  # no draws: no evidence


def test_z_without_spread_is_signed_infinity_or_zero() -> None:
    assert z_score(2.0, 1.0, 0.5) == 2.0
    assert z_score(1.0, 1.0, 0.0) == 0.0
    assert z_score(1.5, 1.0, 0.0) == np.inf
    assert z_score(0.5, 1.0, 0.0) == -np.inf


def test_win_share_counts_ties_as_losses() -> None:
    S = np.array([[1.0, 1.0, 1.0], [0.0, 2.0, 1.0], [5.0, 5.0, 0.0]])
    assert win_share(S, np.ones((3, 3), bool), np.arange(3)) == pytest.approx(1 / 3)
    assert win_share(S, np.ones((3, 3), bool), np.arange(0)) == 0.0


def test_null_test_sees_a_strong_diagonal_and_not_a_flat_matrix() -> None:
    rng = np.random.default_rng(0)
    S = rng.normal(0, 0.05, (20, 20))
    np.fill_diagonal(S, 0.4)
    t = null_test(S, np.ones((20, 20), bool), draws=999)
    assert t is not None and t.rows == 20 and t.wins == 1.0
    assert t.p_value == pytest.approx(1 / 1000) and t.z > 10
    flat = null_test(np.zeros((20, 20)), np.ones((20, 20), bool), draws=99)
    assert flat is not None and flat.z == 0.0 and flat.p_value == 1.0 and flat.wins == 0.0
    assert null_test(S, np.eye(20, dtype=bool)) is None  # no null pair at all
    with pytest.raises(ValueError, match="must be one"):
        null_test(S, np.ones((3, 3), bool))


def _test(z: float, p: float = 0.001, observed: float = 0.3, wins: float = 0.5) -> NullTest:
    return NullTest(observed, 0.0, 0.05, p, z, wins, 24)


def test_ok_boundaries_are_inclusive() -> None:
    th = Thresholds()
    assert decide(_test(th.z_ok, th.p_ok), AMPLE).verdict == OK
    assert decide(_test(np.nextafter(th.z_ok, 0), th.p_ok), AMPLE).verdict == INCONCLUSIVE
    assert decide(_test(th.z_ok, np.nextafter(th.p_ok, 1)), AMPLE).verdict == INCONCLUSIVE


def test_failed_boundary_is_exclusive_and_names_the_pose_cause() -> None:
    th = Thresholds()
    at = decide(_test(th.z_fail, 0.2), AMPLE)
    assert at.verdict == INCONCLUSIVE and "not clearly" in at.reason
    below = decide(_test(np.nextafter(th.z_fail, 0), 0.2), AMPLE)
    assert below.verdict == FAILED and below.cause == POSE_CAUSE
    assert "indistinguishable from the null" in below.reason and "z 2.0" in below.reason
    # a significant search that is not far above still names what it moved as the cause
    near = Search(0.35, th.z_ok, "clock offset (+100 ms)")
    v = decide(_test(np.nextafter(th.z_fail, 0), 0.2, observed=0.3), AMPLE, near)
    assert v.verdict == FAILED and v.cause == "clock offset (+100 ms)"
    weak = Search(0.35, np.nextafter(th.z_ok, 0), "clock offset (+100 ms)")
    assert decide(_test(1.0, 0.2, observed=0.3), AMPLE, weak).cause == POSE_CAUSE


def test_failing_as_the_null_needs_views_to_lose_as_often_as_chance() -> None:
    th = Thresholds()
    below = np.nextafter(th.z_fail, 0)
    assert decide(_test(below, 0.2, wins=np.nextafter(th.wins_fail, 0)), AMPLE).verdict == FAILED
    kept = decide(_test(below, 0.2, wins=th.wins_fail), AMPLE)  # exclusive: not failed
    assert kept.verdict == INCONCLUSIVE and not kept.cause


def test_a_significant_search_far_above_names_what_it_moved() -> None:
    th = Thresholds()
    best = Search(0.4, th.z_ok, "extrinsic rotation (yaw +5 deg)")
    below = float(np.nextafter(th.below_best * 0.4, 0))
    v = decide(_test(8.0, observed=below), AMPLE, best)  # even a significant score fails
    assert v.verdict == FAILED and v.cause == "extrinsic rotation (yaw +5 deg)"
    assert "reaches 0.4000 (z 4.0)" in v.reason
    # at exactly below_best x best the observed score is not "far below" (strict <); it is
    # below near_best x best: not ok, the better geometry named
    at = decide(_test(8.0, observed=th.below_best * 0.4), AMPLE, best)
    assert at.verdict == INCONCLUSIVE and at.cause == best.moved
    assert decide(_test(8.0, observed=th.near_best * 0.4), AMPLE, best).verdict == OK
    # a best that is not itself significant cannot accuse the geometry
    weak = Search(0.4, np.nextafter(th.z_ok, 0), "clock offset (+100 ms)")
    assert decide(_test(8.0, observed=0.1), AMPLE, weak).verdict == OK


@pytest.mark.parametrize(("ev", "words"), [
    (Evidence(7, 5000), "7 view(s)"),
    (Evidence(3, 5000, flat_views=20), "textureless"),
    (Evidence(24, 5000, null_problem="the views' images are alike"), "alike"),
])
def test_thin_evidence_is_inconclusive_never_failed(ev: Evidence, words: str) -> None:
    for z in (-5.0, 0.0, 10.0):
        v = decide(_test(z, 0.9), ev, Search(0.9, 20.0, "clock offset (+50 ms)"))
        assert v.verdict == INCONCLUSIVE and words in v.reason and not v.cause
    assert decide(None, AMPLE).verdict == INCONCLUSIVE
    assert Thresholds().min_views == 8 and decide(_test(10.0), Evidence(8, 300)).verdict == OK


def test_few_edge_points_can_pass_but_never_fail() -> None:
    few = Evidence(24, Thresholds().min_points - 1)
    assert decide(_test(10.0), few).verdict == OK
    low = decide(_test(-5.0, 0.9), few, Search(0.9, 20.0, "clock offset (+50 ms)"))
    assert low.verdict == INCONCLUSIVE and "299 LiDAR edge point(s), 300 needed" in low.reason
    assert decide(_test(-5.0, 0.9), Evidence(24, 300)).verdict == FAILED


def test_a_coarse_scan_can_pass_but_never_fail() -> None:
    th = Thresholds()
    coarse = Evidence(24, 5000, step_deg=np.nextafter(th.max_step_deg, 2))
    assert decide(_test(10.0), coarse).verdict == OK
    v = decide(_test(-5.0, 0.9), coarse, Search(0.9, 20.0, "clock offset (+50 ms)"))
    assert v.verdict == INCONCLUSIVE and "angular step 1.50 deg is too coarse" in v.reason
    fine = Evidence(24, 5000, step_deg=th.max_step_deg)  # inclusive
    assert decide(_test(-5.0, 0.9), fine).verdict == FAILED
