"""The clock-offset estimator over views: candidate grid, per-view scores, the estimate."""

from __future__ import annotations

import numpy as np
import pytest

from bench.support.offset_search import CANDIDATES_S, estimate, view_scores
from bench.support.time_offset import scan_edges
from packets.projection import project_points


def _wall_with_pole() -> tuple[np.ndarray, np.ndarray]:
    """One ring in front of the camera (z forward in the camera frame = x of the LiDAR here):
    a wall at 10 m with a pole at 5 m, so the ring has two depth edges."""
    az = np.linspace(-0.4, 0.4, 81)
    r = np.full(az.size, 10.0)
    r[35:45] = 5.0
    xyz = np.column_stack([r * np.sin(az), np.zeros_like(az), r * np.cos(az)])
    return xyz, np.arange(az.size, dtype=np.int64) * 1000


def _shift(dx: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = dx
    return T


def test_candidate_grid_is_symmetric_and_holds_zero() -> None:
    assert CANDIDATES_S.size == 61
    assert CANDIDATES_S[0] == -0.15 and CANDIDATES_S[-1] == 0.15
    assert np.count_nonzero(CANDIDATES_S == 0.0) == 1
    np.testing.assert_allclose(np.diff(CANDIDATES_S), 0.005, atol=1e-9)


def test_view_scores_peak_where_the_edges_land_on_the_gradient() -> None:
    xyz, t = _wall_with_pole()
    K = np.array([[100.0, 0, 80], [0, 100.0, 30], [0, 0, 1]])
    hw = (60, 160)
    aligned = view_scores(np.ones(hw), xyz, t, K, [np.eye(4)], hw)
    assert aligned[0] == pytest.approx(1.0)  # a flat gradient: no alignment signal
    proj = project_points(xyz, K, np.eye(4), hw)
    grad = np.ones(hw)
    for u, v in np.rint(proj.uv[scan_edges(xyz, t)]).astype(int):
        grad[v, u] = 9.0  # image edges exactly where the LiDAR edges project untransformed
    got = view_scores(grad, xyz, t, K, [_shift(0.3), np.eye(4), None, _shift(-0.3)], hw)
    assert got[2] == 0.0  # no pose: no score
    assert got[1] == got.max() and got[1] > 1.0
    assert got[0] < got[1] and got[3] < got[1]


def test_estimate_returns_the_best_candidate_and_the_peak_over_zero() -> None:
    c = np.array([-0.01, 0.0, 0.01, 0.02])
    out = estimate(c, np.array([1.0, 2.0, 4.0, 1.0]), views=3)
    assert out["views"] == 3
    assert out["score_peak_over_zero"] == pytest.approx(2.0)
    assert 0.0 < out["estimated_s"] < 0.02
    assert np.isnan(estimate(c, np.zeros(4), views=0)["score_peak_over_zero"])


def test_candidates_after_a_missing_pose_are_still_scored_and_undefined_scores_are_zero() -> None:
    xyz, t = _wall_with_pole()
    K = np.array([[100.0, 0, 80], [0, 100.0, 30], [0, 0, 1]])
    hw = (60, 160)
    behind = np.diag([1.0, 1.0, -1.0, 1.0])  # every point behind the camera: no edge score
    got = view_scores(np.ones(hw), xyz, t, K, [None, np.eye(4), behind, np.eye(4)], hw)
    assert got.tolist() == [0.0, pytest.approx(1.0), 0.0, pytest.approx(1.0)]
