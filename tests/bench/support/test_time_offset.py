"""Clock-offset estimation pieces on hand-built scans and images."""

from __future__ import annotations

import numpy as np
import pytest

from bench.support.time_offset import best_offset, edge_score, scan_edges


def _ring(elev_deg: float, ranges: np.ndarray) -> np.ndarray:
    az = np.linspace(-0.5, 0.5, ranges.size)
    e = np.radians(elev_deg)
    return np.column_stack([ranges * np.cos(e) * np.cos(az), ranges * np.cos(e) * np.sin(az),
                            ranges * np.sin(e)])


def test_scan_edges_are_the_near_side_of_each_range_jump() -> None:
    ranges = np.full(40, 10.0)
    ranges[15:25] = 5.0  # a pole in front of a wall
    ranges[30] = 10.5  # 5 %: no edge
    xyz = np.vstack([_ring(-3.0, ranges), _ring(2.0, ranges)])
    t = np.concatenate([np.arange(40), np.arange(40)]) * 1000  # the rings interleave in time
    order = np.random.default_rng(0).permutation(80)  # any storage order
    got = scan_edges(xyz[order], t[order])
    np.testing.assert_array_equal(np.sort(order[got]), [15, 24, 55, 64])


def test_edge_score_closed_form() -> None:
    grad = np.ones((10, 20))
    grad[:, 7] = 5.0
    all_uv = np.array([[7.0, 1.0], [3.0, 2.0], [12.0, 5.0], [7.2, 8.9]])
    assert edge_score(grad, all_uv[[0, 3]], all_uv) == pytest.approx(5.0 / 3.0)
    assert np.isnan(edge_score(grad, np.zeros((0, 2)), all_uv))


def test_best_offset_refines_a_parabola_exactly() -> None:
    c = np.round(np.arange(-0.1, 0.1001, 0.01), 6)
    assert best_offset(c, -((c - 0.0123) ** 2)) == pytest.approx(0.0123, abs=1e-12)
    assert best_offset(c, -np.abs(c + 0.1)) == pytest.approx(-0.1)  # at the grid's end
    assert np.isnan(best_offset(c, np.full(c.size, np.nan)))


def _axis_ring(ranges: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Returns of one ring along the x axis (ranges exact), fired in list order."""
    xyz = np.zeros((len(ranges), 3))
    xyz[:, 0] = ranges
    return xyz, np.arange(len(ranges)) * 1000


def test_scan_edge_bound_is_exclusive() -> None:
    # 10 -> 11 and 11 -> 10 jump by exactly 0.1 x the nearer range: no edge; 10 -> 12 is one
    xyz, t = _axis_ring([10.0, 11.0, 10.0, 12.0])
    np.testing.assert_array_equal(scan_edges(xyz, t), [2])


def test_scan_edges_skip_zero_and_infinite_returns_and_see_sub_metre_ones() -> None:
    xyz, t = _axis_ring([0.5, 0.25, 0.0, np.inf, 0.25])  # 0 and Inf: no return
    np.testing.assert_array_equal(scan_edges(xyz, t), [1])  # 0.5 -> 0.25: its near side


def test_edge_score_is_nan_without_points_or_without_gradient() -> None:
    uv = np.array([[1.0, 1.0], [2.0, 3.0]])
    assert np.isnan(edge_score(np.ones((5, 5)), uv, np.zeros((0, 2))))
    assert np.isnan(edge_score(np.zeros((5, 5)), uv, uv))  # mean over all points 0


C = np.round(np.arange(0.0, 0.0501, 0.01), 6)  # 6 candidates, 10 ms apart


def _peak(at: float) -> np.ndarray:
    return -((C - at) ** 2)


def test_best_offset_refines_next_to_either_end_and_stops_at_the_ends() -> None:
    assert best_offset(C, _peak(0.012)) == pytest.approx(0.012, abs=1e-12)  # index 1
    assert best_offset(C, _peak(0.038)) == pytest.approx(0.038, abs=1e-12)  # index size - 2
    assert best_offset(C, _peak(0.07)) == C[-1]  # the last candidate: no neighbour beyond it
    assert best_offset(C, _peak(-0.02)) == C[0]


def test_best_offset_refines_only_over_finite_neighbours() -> None:
    s = _peak(0.022)  # index 2
    for j in (1, 3):
        unrefined = s.copy()
        unrefined[j] = -np.inf
        assert best_offset(C, unrefined) == C[2]
    far = s.copy()
    far[[0, 4]] = np.nan  # neighbours of the neighbours do not matter
    assert best_offset(C, far) == pytest.approx(0.022, abs=1e-12)
