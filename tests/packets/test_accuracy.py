"""Packet accuracy metrics on hand-built scenes whose answers are known in closed form."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.accuracy import (
    abs_rel,
    cell_reference,
    depth_errors,
    dtau_bins,
    packet_depth,
    slope,
    support_depth,
)
from packets.assemble import view_support
from packets.statistics import cell_depth_stats, explicit_channels
from packets.support import front_margins, front_surface

P = 14
HW = (4 * P, 6 * P)
K = np.array([[60.0, 0.0, (HW[1] - 1) / 2], [0.0, 60.0, (HW[0] - 1) / 2], [0.0, 0.0, 1.0]])


def _plane_points(depth: float, n: int = 40) -> np.ndarray:
    """Points on the fronto-parallel plane z = depth filling the view (camera frame)."""
    u, v = np.meshgrid(np.linspace(0, HW[1] - 1, 3 * n), np.linspace(0, HW[0] - 1, 2 * n))
    x = (u.ravel() - K[0, 2]) / K[0, 0] * depth
    y = (v.ravel() - K[1, 2]) / K[1, 1] * depth
    return np.column_stack([x, y, np.full(x.size, depth)])


def test_plane_reference_is_its_depth_with_no_spread_and_no_border() -> None:
    ref = cell_reference(np.full(HW, 3.5), P)
    np.testing.assert_array_equal(ref.median, 3.5)
    np.testing.assert_array_equal(ref.spread, 0.0)
    assert not ref.border.any() and ref.valid.all()


def test_step_marks_the_cells_it_crosses_as_border() -> None:
    d = np.full(HW, 5.0)
    d[:, : 2 * P + 4] = 2.0  # a near slab over columns 0..31: the step is inside cell column 2
    ref = cell_reference(d, P)
    assert ref.border[:, 2].all() and not ref.border[:, [0, 1, 3, 4, 5]].any()
    np.testing.assert_array_equal(ref.median[:, 2], 5.0)  # 10 of 14 columns see the far plane
    np.testing.assert_allclose(ref.spread[:, 2], 3.0)  # p90 - p10 over 2 m and 5 m pixels


def test_step_on_a_cell_edge_marks_both_neighbours() -> None:
    d = np.full(HW, 5.0)
    d[:, : 2 * P] = 2.0
    ref = cell_reference(d, P)
    assert ref.border[:, [1, 2]].all() and not ref.border[:, [0, 3]].any()


def test_sky_cells_have_no_reference_and_their_edge_is_a_border() -> None:
    d = np.full(HW, 4.0)
    d[:P] = 0.0  # sky in the top cell row
    d[P : P + 3] = np.inf  # non-finite counts as no surface too
    ref = cell_reference(d, P)
    assert np.isnan(ref.median[0]).all() and not ref.border[0].any()
    assert ref.border[1].all() and not ref.border[2:].any()
    np.testing.assert_array_equal(ref.median[1], 4.0)


def test_errors_closed_form() -> None:
    ref = np.array([2.0, 4.0, 5.0, 10.0])
    pred = ref * np.array([1.02, 0.9, 1.3, 1.0])
    e = depth_errors(pred, ref)
    assert e.n == 4
    assert e.abs_rel == pytest.approx((0.02 + 0.1 + 0.3 + 0.0) / 4)
    assert e.rmse_m == pytest.approx(np.sqrt((0.04**2 + 0.4**2 + 1.5**2) / 4))
    assert e.delta == {1.05: 0.5, 1.25: 0.75}  # 1/0.9 = 1.11 is within 1.25, not 1.05
    nan = depth_errors([np.nan, 1.0], [1.0, np.nan])
    assert nan.n == 0 and np.isnan(nan.abs_rel)
    np.testing.assert_allclose(abs_rel([3.0, 0.0], [2.0, 2.0]), [0.5, np.nan])


def test_slope_and_bins() -> None:
    assert slope([0, 1, 2, 3], [1.0, 1.5, 2.0, 2.5]) == pytest.approx(0.5)
    assert np.isnan(slope([1.0, 1.0], [0.0, 1.0]))
    np.testing.assert_array_equal(dtau_bins([0.0, 0.005, 0.01, 0.3], (0.0, 0.01, 0.1)),
                                  [0, 0, 1, 2])


def test_packet_depth_of_g_is_the_cell_mean_and_float16_within_half_ulp() -> None:
    cell = np.array([0, 0, 5, 7])
    depth = np.array([2.0, 4.0, 10.0, 0.7])
    g = explicit_channels(cell_depth_stats(cell, depth, 8), 0.02, (2, 4))
    got = packet_depth(g)
    want = np.full((2, 4), np.nan)
    want.flat[[0, 5, 7]] = [3.0, 10.0, 0.7]
    np.testing.assert_allclose(got, want, rtol=1e-7)
    half = packet_depth(g.astype(np.float16))
    rel = np.abs(half - want)[np.isfinite(want)] / want[np.isfinite(want)]
    assert rel.max() <= 2.0**-11 * 1.001  # float16 rounding of 1/d: at most half an ulp
    np.testing.assert_array_equal(support_depth(cell, depth, (2, 4)), want)


@pytest.mark.parametrize("shift", [0.0, 0.1, -0.25])
def test_plane_with_known_travel_has_abs_rel_travel_over_depth(shift: float) -> None:
    """A fronto-parallel plane at 5 m; the LiDAR frame is wrong by `shift` m along the optical
    axis (the robot's travel v * Δτ without the odometry chain): g sees 5 + shift everywhere."""
    D = 5.0
    T = np.eye(4)
    T[2, 3] = shift
    sup = view_support(_plane_points(D), K, T, HW, patch=P)
    got = support_depth(sup.cell, sup.depth, sup.grid_hw)
    ref = cell_reference(np.full(HW, D), P)
    e = depth_errors(got, ref.median)
    assert e.n == ref.median.size  # every cell supported
    assert e.abs_rel == pytest.approx(abs(shift) / D, abs=1e-12)
    assert e.rmse_m == pytest.approx(abs(shift), abs=1e-12)


def test_relative_front_margin_follows_depth() -> None:
    np.testing.assert_allclose(front_margins(np.array([1.0, 10.0]), 0.1, 0.2), [0.3, 2.1])
    with pytest.raises(ValueError, match="relative margin"):
        front_margins(np.ones(1), 0.1, -1.0)
    sup = view_support(np.array([[0, 0, 10.0], [0, 0, 11.0], [0, 0, 12.5], [0, 0, 12.0]]),
                       K, np.eye(4), HW, patch=P)
    fixed = front_surface(sup, 0.5)
    rel = front_surface(sup, 0.1, 0.2)  # margin 0.1 + 0.2 * 10 = 2.1 m behind 10 m
    assert fixed.n_front_dropped == 3 and sorted(rel.depth) == [10.0, 11.0, 12.0]


@settings(max_examples=40, deadline=None)
@given(st.floats(0.2, 500.0), st.floats(-0.5, 0.5))
def test_abs_rel_of_a_scaled_plane_is_exact(depth: float, rel_err: float) -> None:
    ref = cell_reference(np.full(HW, depth), P)
    e = depth_errors(ref.median * (1.0 + rel_err), ref.median)
    assert e.abs_rel == pytest.approx(abs(rel_err), rel=1e-9, abs=1e-15)
    assert e.delta[1.25] == float(max(1.0 + rel_err, 1.0 / (1.0 + rel_err)) < 1.25)
