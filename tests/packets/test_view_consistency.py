"""Reprojection consistency of a target image: closed forms (0 at the reprojection, a known
error for a known shift or offset, monotone), the undefined cases, and properties."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.projection import bilinear, in_image
from packets.reprojection import subcell_pixels
from packets.view_consistency import INTERIOR_PX, Reads, image_consistency, reads

HW = (28, 84)  # image pixels; grid 2 x 6 cells of 14 px
GRID = (2, 6)
F = 30.0
K = np.array([[F, 0.0, 41.5], [0.0, F, 13.5], [0.0, 0.0, 1.0]])
Z = 5.0  # a fronto-parallel plane (m)
SLOPE = 2.0  # grey levels per pixel column


def pose(tx: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = tx
    return T


def ramp(shift: float = 0.0) -> np.ndarray:
    """(h, w, 3) float image SLOPE * (u + shift) in every channel and row."""
    u = np.arange(HW[1], dtype=np.float64) + shift
    return np.broadcast_to((SLOPE * u)[None, :, None], (*HW, 3)).copy()


def score(candidate: np.ndarray, shift_px: float = 0.0) -> float:
    """Error of one candidate against the ramp source seen from a target camera moved
    shift_px pixels' worth right (plane at Z, full support, source 0 everywhere)."""
    at = reads(np.full(GRID, Z), K, pose(shift_px * Z / F), K[None], pose()[None],
               np.zeros(GRID, np.int64), HW)
    c = image_consistency(candidate[None], ramp()[None], at)
    assert c is not None
    return float(c.errors[0]) * 255.0  # grey levels


def test_a_target_equal_to_its_reprojection_scores_exactly_zero() -> None:
    for s in (0, 1, 3, 7):
        assert score(ramp(s), s) == pytest.approx(0.0, abs=1e-9)


def test_a_shifted_target_scores_its_shift_and_grows_monotonically() -> None:
    """The candidate is the unmoved view; the target camera moves s px: error SLOPE * s."""
    errors = [score(ramp(), s) for s in (0, 1, 2, 4, 8)]
    np.testing.assert_allclose(errors, [SLOPE * s for s in (0, 1, 2, 4, 8)], atol=1e-9)
    assert all(a < b for a, b in itertools.pairwise(errors))


def test_a_constant_offset_scores_its_magnitude() -> None:
    for c in (-20.0, 5.0, 30.0):
        assert score(ramp() + c) == pytest.approx(abs(c), rel=1e-12)


def test_points_that_leave_the_source_are_not_scored() -> None:
    all_in = reads(np.full(GRID, Z), K, pose(), K[None], pose()[None],
                   np.zeros(GRID, np.int64), HW)
    assert len(all_in.src) == GRID[0] * GRID[1] * 16
    moved = reads(np.full(GRID, Z), K, pose(14 * Z / F), K[None], pose()[None],
                  np.zeros(GRID, np.int64), HW)
    assert 0 < len(moved.src) < len(all_in.src)  # the last column of points falls off
    assert in_image(moved.uv_src, HW, INTERIOR_PX).all()


def test_no_support_or_no_source_has_no_score() -> None:
    for depth, chosen in ((np.zeros(GRID), np.zeros(GRID, np.int64)),
                          (np.full(GRID, Z), np.full(GRID, -1, np.int64))):
        at = reads(depth, K, pose(), K[None], pose()[None], chosen, HW)
        assert len(at.src) == 0 and image_consistency(ramp()[None], ramp()[None], at) is None


def test_each_point_is_read_from_its_cells_source() -> None:
    chosen = np.zeros(GRID, np.int64)
    chosen[:, 3:] = 1
    at = reads(np.full(GRID, Z), K, pose(), K[None].repeat(2, 0), pose()[None].repeat(2, 0),
               chosen, HW)
    srcs = np.stack([ramp(), ramp() + 10.0])  # source 1 is 10 levels brighter
    c = image_consistency(np.stack([ramp()]), srcs, at)
    assert c is not None and c.points == 192
    assert c.errors[0] * 255 == pytest.approx(np.sqrt(0.5) * 10.0)  # half the points off by 10


def test_subcell_pixels_are_centred_in_their_cells() -> None:
    uv = subcell_pixels(GRID, HW, 4)
    assert uv.shape == (*GRID, 16, 2)
    np.testing.assert_allclose(uv.mean(axis=2)[0, 0], [6.5, 6.5])
    assert in_image(uv, HW, INTERIOR_PX).all()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(1e-3, 1e3))
def test_error_is_nonnegative_finite_and_zero_only_for_the_reference(seed: int,
                                                                    scale: float) -> None:
    rng = np.random.default_rng(seed)
    src = rng.random((1, *HW, 3)) * scale
    at = Reads(rng.random((20, 2)) * [HW[1] - 1, HW[0] - 1], np.zeros(20, np.int64),
               rng.random((20, 2)) * [HW[1] - 1, HW[0] - 1])
    ref = bilinear(src[0], at.uv_src)
    same = np.zeros((*HW, 3))
    c = image_consistency(np.stack([same, src[0]]), src, at, scale=1.0)
    assert c is not None and np.isfinite(c.errors).all() and (c.errors >= 0).all()
    assert c.errors[0] == pytest.approx(np.sqrt(np.mean(ref ** 2)), rel=1e-12)
