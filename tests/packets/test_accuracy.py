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
from schemas.errors import DataError

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


# --- boundaries the mutation run asked for ------------------------------------------------------

def test_a_step_of_exactly_five_percent_is_not_a_border() -> None:
    """20 m next to 21 m: |21 - 20| = 0.05 x 20 exactly, not more (the bound is exclusive);
    21.5 m is a discontinuity."""
    d = np.full((4, 4), 20.0)
    d[:, 2:] = 21.0
    assert not cell_reference(d, 2).border.any()
    d[:, 2:] = 21.5
    np.testing.assert_array_equal(cell_reference(d, 2).border, [[True, True], [True, True]])


def test_near_surfaces_have_borders_too() -> None:
    """A step between surfaces under 1 m (0.5 m to 0.8 m) is a discontinuity like any other."""
    d = np.full((4, 4), 0.5)
    d[2:] = 0.8
    np.testing.assert_array_equal(cell_reference(d, 2).border, [[True, True], [True, True]])
    np.testing.assert_array_equal(cell_reference(d, 2).median, [[0.5, 0.5], [0.8, 0.8]])


def test_border_threshold_follows_the_nearer_depth_of_each_pair() -> None:
    """A 4 % step far down the image is no border even when the top row is much nearer; a real
    step under a row of sky is one."""
    d = np.full((6, 2), 10.0)
    d[0] = 1.0
    d[4:] = 10.4
    assert cell_reference(d, 2).border[:, 0].tolist() == [True, False, False]
    d[0] = 0.0  # sky on top
    d[4:] = 12.0
    assert cell_reference(d, 2).border[:, 0].tolist() == [True, True, True]


def test_half_the_pixels_on_a_surface_is_enough() -> None:
    d = np.array([[3.0, 0.0], [0.0, 5.0]])
    ref = cell_reference(d, 2)
    assert ref.valid.tolist() == [[True]]
    assert ref.median[0, 0] == 4.0
    d[1, 1] = 0.0
    assert cell_reference(d, 2).valid.tolist() == [[False]]


def test_reference_median_and_spread_are_per_cell() -> None:
    d = np.zeros((4, 8))
    d[:, :4] = np.arange(1.0, 17.0).reshape(4, 4)
    d[:, 4:] = 7.0
    ref = cell_reference(d, 4)
    np.testing.assert_array_equal(ref.median, [[8.5, 7.0]])
    np.testing.assert_allclose(ref.spread, [[14.5 - 2.5, 0.0]], rtol=1e-15)  # p90 - p10


def test_float32_depth_maps_give_the_float64_reference() -> None:
    d = np.array([[1.1, 1.2], [1.3, 1.7]], dtype=np.float32)
    assert cell_reference(d, 2).median[0, 0] == np.median(d.astype(np.float64))
    assert cell_reference(d, 1).median.dtype == np.float64


@pytest.mark.parametrize(("shape", "patch"), [((4, 4, 1), 2), ((5, 4), 2), ((4, 5), 2),
                                              ((4, 4), 0), ((4, 4), -2)])
def test_bad_depth_maps_and_patches_are_refused(shape: tuple[int, ...], patch: int) -> None:
    with pytest.raises(DataError, match=rf"^depth map \(.*\) must be 2-D with sides multiple "
                                        rf"of {patch}$"):
        cell_reference(np.ones(shape), patch)


def test_a_patch_of_one_pixel_is_its_own_cell() -> None:
    d = np.array([[2.0, 0.0], [3.0, 4.0]])
    ref = cell_reference(d, 1)
    np.testing.assert_array_equal(ref.median, [[2.0, np.nan], [3.0, 4.0]])


def test_abs_rel_is_nan_without_a_positive_pair_and_warns_nothing() -> None:
    got = abs_rel([1.0, 0.0, 2.0, np.nan, 0.5, 3.0], [0.0, 0.0, np.nan, 2.0, 1.0, 0.5])
    np.testing.assert_array_equal(got, [np.nan, np.nan, np.nan, np.nan, 0.5, 5.0])
    p32, r32 = np.array([1.1], np.float32), np.array([1.3], np.float32)
    want = abs(p32.astype(np.float64) - r32.astype(np.float64)) / r32.astype(np.float64)
    np.testing.assert_array_equal(abs_rel(p32, r32), want)


def test_depth_errors_leave_out_non_positive_pairs_and_count_ratios_strictly() -> None:
    e = depth_errors([2.0, 5.0, 21.0, 3.0, 0.0, 4.0], [2.0, 4.0, 20.0, -1.0, 1.0, 0.0])
    assert e.n == 3  # (3, -1), (0, 1) and (4, 0) left out
    assert e.delta == {1.05: 1 / 3, 1.25: 2 / 3}  # 21/20 = 1.05 and 5/4 = 1.25 are not within
    assert e.abs_rel == pytest.approx((0.0 + 0.25 + 0.05) / 3, rel=1e-15)


def test_depth_errors_of_nothing_are_nan_and_flatten_with_a_prefix() -> None:
    e = depth_errors([], [])
    assert e.n == 0 and np.isnan(e.abs_rel) and np.isnan(e.rmse_m)
    assert set(e.delta) == {1.05, 1.25} and all(np.isnan(v) for v in e.delta.values())
    assert set(depth_errors([2.0], [4.0]).as_dict()) == {"n", "abs_rel", "rmse_m", "delta_1.05",
                                                         "delta_1.25"}
    flat = depth_errors([2.0], [4.0]).as_dict("all_")
    assert flat == {"all_n": 1, "all_abs_rel": 0.5, "all_rmse_m": 2.0, "all_delta_1.05": 0.0,
                    "all_delta_1.25": 0.0}
    with pytest.raises(DataError, match=r"^pred \(2,\) and ref \(3,\) must have the same size$"):
        depth_errors([1.0, 2.0], [1.0, 2.0, 3.0])


def test_depth_errors_compute_float32_inputs_in_float64() -> None:
    rng = np.random.default_rng(0)
    p, r = rng.uniform(1, 50, 1000).astype(np.float32), rng.uniform(1, 50, 1000).astype(np.float32)
    assert depth_errors(p, r) == depth_errors(p.astype(np.float64), r.astype(np.float64))


def test_packet_depth_reads_validity_and_inverse_depth() -> None:
    g = np.zeros((6, 1, 5))
    g[0] = [1.0, 0.0, 1.0, 1.0, 1.0]
    g[2] = [0.5, 0.5, 0.0, 0.25, 4.0]  # cell 1 empty (validity 0), cell 2 without 1/d
    np.testing.assert_array_equal(packet_depth(g), [[2.0, np.nan, np.nan, 4.0, 0.25]])
    np.testing.assert_array_equal(packet_depth(g[:3]), packet_depth(g))
    g32 = g.astype(np.float32)
    g32[2, 0, 3] = np.float32(0.3)
    assert packet_depth(g32)[0, 3] == 1.0 / np.float64(np.float32(0.3))
    for bad in (np.zeros((6, 4)), np.zeros((2, 3, 4))):
        with pytest.raises(DataError, match=rf"^g must be \(6, H, W\), got shape "
                                            rf"\({bad.shape[0]}, "):
            packet_depth(bad)


def test_slope_edges() -> None:
    assert slope([1.0, 2.0], [3.0, 5.0]) == 2.0  # two points suffice
    assert slope([0.0, 1.0, 2.0, 5.0], [0.0, 1.0, np.nan, 9.0]) == pytest.approx(
        slope([0.0, 1.0, 5.0], [0.0, 1.0, 9.0]), rel=1e-15)  # the NaN pair is left out
    assert np.isnan(slope([1.0, np.nan], [2.0, 3.0]))
    x = np.array([0.1, 0.2, 0.7])
    assert slope(x, 1e12 + 2.0 * x) == pytest.approx(2.0, rel=1e-3)
    x32 = np.array([0.1, 0.2, 0.7, 1.3], np.float32)
    y32 = np.array([1.0, 1.1, 2.9, 3.3], np.float32)
    assert slope(x32, y32) == slope(x32.astype(np.float64), y32.astype(np.float64))
