"""Clock-offset estimation pieces on hand-built scans and images."""

from __future__ import annotations

import numpy as np
import pytest

from packets.time_offset import best_offset, edge_score, scan_edges


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
