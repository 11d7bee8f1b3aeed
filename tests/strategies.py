"""Shared hypothesis strategies (append new ones at the end)."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

# --- packets (issue 5) ---------------------------------------------------------------------

depths_m = st.floats(min_value=1e-3, max_value=1e4, allow_nan=False, allow_infinity=False)
"""Camera depths across the range the packet math must be stable on (metres)."""

delta_tau_s = st.one_of(
    st.just(0.0),
    st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False),
)
"""Signed sweep-image offsets in seconds, zero and large included."""

non_finite = st.sampled_from([np.nan, np.inf, -np.inf])


@st.composite
def cells_and_depths(draw: st.DrawFn, n_cells: int = 12, max_points: int = 60) -> tuple:
    """(cell (M,) int64 in [0, n_cells), depth (M,) float64 metres), M possibly 0."""
    m = draw(st.integers(min_value=0, max_value=max_points))
    cell = draw(hnp.arrays(np.int64, m, elements=st.integers(0, n_cells - 1)))
    depth = draw(hnp.arrays(np.float64, m, elements=depths_m))
    return cell, depth


@st.composite
def pinhole_K(draw: st.DrawFn, hw: tuple[int, int] = (28, 42)) -> np.ndarray:
    """(3, 3) float64 OpenCV intrinsics, principal point near the centre, FOV under ~60 deg."""
    f = draw(st.floats(min_value=40.0, max_value=400.0))
    fy = f * draw(st.floats(min_value=0.8, max_value=1.25))
    cx = (hw[1] - 1) / 2 + draw(st.floats(-3.0, 3.0))
    cy = (hw[0] - 1) / 2 + draw(st.floats(-3.0, 3.0))
    return np.array([[f, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@st.composite
def rigid_transforms(draw: st.DrawFn) -> np.ndarray:
    """(4, 4) float64 rigid transform: random unit-quaternion rotation, translation within 5 m."""
    q = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    norm = np.linalg.norm(q)
    q = np.array([1.0, 0.0, 0.0, 0.0]) if norm < 1e-3 else q / norm
    w, x, y, z = q
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = draw(st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3))
    return T


# --- ingest / select (issue 4) --------------------------------------------------------------


@st.composite
def unit_quaternions(draw: st.DrawFn) -> np.ndarray:
    """(4,) float64 unit quaternion (x, y, z, w), either sign of w."""
    q = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    norm = np.linalg.norm(q)
    return np.array([0.0, 0.0, 0.0, 1.0]) if norm < 1e-3 else q / norm


stamps_ns = st.integers(min_value=0, max_value=2**62)
"""Absolute int64 nanosecond stamps, large enough that float64 seconds would lose precision."""


# --- encoders (issue 6) --------------------------------------------------------------------


@st.composite
def uint8_patch_images(draw: st.DrawFn, max_cells: int = 3, max_batch: int = 2) -> np.ndarray:
    """uint8 (B, 14h, 14w, 3) images, B in 1..max_batch, extremes 0 and 255 included."""
    b = draw(st.integers(1, max_batch))
    h = 14 * draw(st.integers(1, max_cells))
    w = 14 * draw(st.integers(1, max_cells))
    return draw(hnp.arrays(np.uint8, (b, h, w, 3),
                           elements=st.one_of(st.sampled_from([0, 255]), st.integers(0, 255))))


# --- alignment diagnostics (issue 9) -------------------------------------------------------


@st.composite
def feature_pairs(draw: st.DrawFn, max_cells: int = 40, max_channels: int = 24) -> tuple:
    """(X (n, p), Y (n, q)) float64 Gaussian features sharing a rank-2 signal, n >= 5."""
    n = draw(st.integers(5, max_cells))
    p, q = draw(st.integers(2, max_channels)), draw(st.integers(2, max_channels))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    z = rng.standard_normal((n, 2))
    x = z @ rng.standard_normal((2, p)) + rng.standard_normal((n, p))
    y = z @ rng.standard_normal((2, q)) + rng.standard_normal((n, q))
    return x, y


@st.composite
def orthogonal_matrices(draw: st.DrawFn, dim: int) -> np.ndarray:
    """(dim, dim) float64 random orthogonal matrix (reflections included), from a drawn seed."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    q, r = np.linalg.qr(rng.standard_normal((dim, dim)))
    return q * np.sign(np.diag(r))[None, :] * draw(st.sampled_from([1.0, -1.0]))


# --- synth (issue 3) -----------------------------------------------------------------------

fisheye_D = st.tuples(
    st.floats(-0.05, 0.05), st.floats(-0.01, 0.01), st.floats(-0.002, 0.002),
    st.floats(-0.0005, 0.0005),
).map(lambda d: np.array(d, dtype=np.float64))  # fmt: skip
"""Equidistant coefficients k1..k4 for which theta_d(theta) stays monotone up to ~80 deg."""

walk_times_s = st.floats(min_value=-5.0, max_value=600.0, allow_nan=False, allow_infinity=False)
"""Times (s since t0) at which a synthetic trajectory is evaluated."""
