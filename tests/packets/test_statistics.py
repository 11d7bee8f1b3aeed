"""Explicit statistics: agreement with the float64 reference, exact zeros, extremes, eq. 9."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.support.packet_reference import reference_cell_stats, reference_explicit
from packets.statistics import CHANNELS, CellStats, cell_depth_stats, explicit_channels
from schemas.errors import DataError
from tests.strategies import cells_and_depths, delta_tau_s, depths_m, non_finite

N_CELLS = 12


def _assert_var_close(var: np.ndarray, ref: np.ndarray, mean: np.ndarray) -> None:
    # 1e-6 relative, plus the float64 rounding floor of squared deviations about the mean
    # (nearly equal depths give variances ~1e-38 whose relative error means nothing)
    assert np.all(np.abs(var - ref) <= 1e-6 * ref + 1e-14 * mean * mean)


@settings(max_examples=150, deadline=None)
@given(cd=cells_and_depths(n_cells=N_CELLS))
def test_agrees_with_reference(cd: tuple[np.ndarray, np.ndarray]) -> None:
    cell, depth = cd
    s = cell_depth_stats(cell, depth, N_CELLS)
    n, mean, var = reference_cell_stats(cell, depth, N_CELLS)
    np.testing.assert_array_equal(s.n, n)
    np.testing.assert_allclose(s.mean, mean, rtol=1e-12, atol=0)
    _assert_var_close(s.var, var, mean)
    assert np.all(s.var >= 0)


@settings(max_examples=100, deadline=None)
@given(d=depths_m, n=st.integers(1, 2000), q=st.integers(0, N_CELLS - 1))
def test_constant_depth_variance_exactly_zero(d: float, n: int, q: int) -> None:
    s = cell_depth_stats(np.full(n, q), np.full(n, d), N_CELLS)
    assert s.var[q] == 0.0 and s.mean[q] == d and s.n[q] == n


def test_million_points_in_one_cell_no_cancellation() -> None:
    rng = np.random.default_rng(0)
    depth = 1e4 + rng.uniform(-1e-3, 1e-3, 1_000_000)  # true variance ~3.3e-7 m^2 at 10 km
    cell = np.full(depth.size, 7)
    s = cell_depth_stats(cell, depth, N_CELLS)
    ref = np.mean((depth - depth.mean()) ** 2)
    naive = np.mean(depth**2) - np.mean(depth) ** 2  # what cancellation does
    assert abs(naive - ref) > 1e-2 * ref  # the test data does defeat the one-pass formula
    assert s.n[7] == 1_000_000
    np.testing.assert_allclose(s.var[7], ref, rtol=1e-6)
    np.testing.assert_allclose(s.mean[7], depth.mean(), rtol=1e-12)


@settings(max_examples=100, deadline=None)
@given(cd=cells_and_depths(n_cells=N_CELLS), dt=delta_tau_s)
def test_explicit_channels_eq9(cd: tuple[np.ndarray, np.ndarray], dt: float) -> None:
    cell, depth = cd
    s = cell_depth_stats(cell, depth, N_CELLS)
    g = explicit_channels(s, dt, (3, 4))
    ref = reference_explicit(*reference_cell_stats(cell, depth, N_CELLS), dt, (3, 4))
    assert g.dtype == np.float32 and g.shape == (len(CHANNELS), 3, 4)
    assert np.isfinite(g).all()
    np.testing.assert_allclose(g, ref.astype(np.float32), rtol=2e-6, atol=1e-30)
    empty = (s.n == 0).reshape(3, 4)
    assert np.all(g[:, empty] == 0)
    assert np.all(g[0, ~empty] == 1) and np.all(g[5, ~empty] == np.float32(dt))


def test_empty_grid_all_zero() -> None:
    g = explicit_channels(cell_depth_stats(np.zeros(0, np.int64), np.zeros(0), 6), 0.05, (2, 3))
    assert g.shape == (6, 2, 3) and not g.any()


@given(bad=non_finite)
def test_non_finite_rejected(bad: float) -> None:
    with pytest.raises(ValueError, match="depth"):
        cell_depth_stats(np.array([0, 1]), np.array([1.0, bad]), 4)
    s = cell_depth_stats(np.array([0]), np.array([1.0]), 4)
    with pytest.raises(ValueError, match="delta_tau_s"):
        explicit_channels(s, bad, (2, 2))


def test_float32_overflow_rejected() -> None:
    s = cell_depth_stats(np.array([0, 0]), np.array([1e20, 3e20]), 1)
    with pytest.raises(ValueError, match="depth_variance"):
        explicit_channels(s, 0.0, (1, 1))


def test_bad_cells_rejected() -> None:
    with pytest.raises(ValueError, match="cell ids"):
        cell_depth_stats(np.array([0, 5]), np.array([1.0, 2.0]), 4)
    with pytest.raises(ValueError, match="positive mean"):
        explicit_channels(CellStats(np.array([1]), np.array([0.0]), np.array([0.0])), 0.0, (1, 1))


# --- boundaries the mutation run asked for ------------------------------------------------------


def test_variance_of_nearly_equal_depths_far_from_zero_is_exact() -> None:
    """Depths 1e4 m apart by one and two ulps: the mean is not representable, so the sum of
    deviations is not zero and its correction term decides the result (against exact
    rational arithmetic)."""
    ulp = np.spacing(1e4)
    depth = np.array([1e4, 1e4 + ulp, 1e4 + 2 * ulp, 1e4 + 2 * ulp])
    got = cell_depth_stats(np.zeros(4, np.int64), depth, 1)
    exact = [Fraction(float(v)) for v in depth]
    mean = sum(exact) / 4
    var = sum((v - mean) ** 2 for v in exact) / 4
    assert got.var[0] == pytest.approx(float(var), rel=1e-6, abs=0.0)


def test_cell_ids_of_any_integer_type_and_the_last_cell() -> None:
    depth = np.array([1.0, 2.0, 4.0])
    for dtype in (np.int32, np.uint64, np.uint8):
        got = cell_depth_stats(np.array([0, 2, 2], dtype=dtype), depth, 3)
        assert got.n.tolist() == [1, 0, 2] and got.mean.tolist() == [1.0, 0.0, 3.0]


@pytest.mark.parametrize(("cell", "depth", "message"), [
    ([0, 3], [1.0, 2.0], r"^cell ids must lie in \[0, 3\), got \[0, 3\]$"),
    ([-1, 0], [1.0, 2.0], r"^cell ids must lie in \[0, 3\), got \[-1, 0\]$"),
    ([0, 1], [1.0], r"^cell \(2,\) and depth \(1,\) must be equal 1-D shapes$"),
    ([[0]], [[1.0]], r"^cell \(1, 1\) and depth \(1, 1\) must be equal 1-D shapes$"),
    ([0, 1], [1.0, np.nan], r"^depth has 1 non-finite value"),
])
def test_bad_cells_and_depths_are_refused_by_name(cell: list, depth: list, message: str) -> None:
    with pytest.raises(DataError, match=message):
        cell_depth_stats(np.array(cell), np.array(depth), 3)


def test_explicit_channels_refusals_name_their_cause() -> None:
    stats = cell_depth_stats(np.array([0]), np.array([2.0]), 2)
    with pytest.raises(DataError, match=r"^delta_tau_s must be finite, got nan$"):
        explicit_channels(stats, float("nan"), (1, 2))
    bad = CellStats(n=np.array([1, 0]), mean=np.array([0.0, 0.0]), var=np.zeros(2))
    with pytest.raises(DataError, match=r"^occupied cells need a positive mean depth \(eq. 8: "
                                        r"d_k > 0\)$"):
        explicit_channels(bad, 0.0, (1, 2))
