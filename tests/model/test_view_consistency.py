"""Reprojection consistency of a target latent: closed forms (0 at the reprojection, a known
error for a known shift or offset, monotone), the undefined cases, and properties."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from model.reprojection import Warp, warp_latents
from model.view_consistency import consistency_of, masked_rms, reprojection_consistency

HW = (28, 84)  # image pixels; grid 2 x 6 cells of 14 px
GRID = (2, 6)
K = np.array([[30.0, 0.0, 41.5], [0.0, 30.0, 13.5], [0.0, 0.0, 1.0]])
Z = 5.0  # a fronto-parallel plane (m)
SLOPE = 0.7  # latent units per cell column


def pose(tx: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = tx
    return T


def ramp(shift: float = 0.0, C: int = 3) -> np.ndarray:
    """(C, H, W) latent SLOPE * (col - shift) in every channel and row."""
    cols = np.arange(GRID[1], dtype=np.float64) - shift
    return np.broadcast_to(SLOPE * cols, (C, *GRID)).copy()


def score(candidate: np.ndarray, tx_target: float = 0.0) -> float:
    """Error of one candidate target latent against the ramp source seen from a target
    camera moved tx_target m right (plane at Z, full support)."""
    c = reprojection_consistency(candidate[None], ramp()[None], np.full(GRID, Z), K,
                                 pose(tx_target), K[None], pose()[None],
                                 np.full((1, *GRID), Z), HW)
    assert c is not None
    return float(c.errors[0])


def test_a_target_equal_to_its_reprojection_scores_exactly_zero() -> None:
    cell_m = (HW[1] / GRID[1]) * Z / K[0, 0]
    for tx in (0.0, cell_m, 2 * cell_m):
        w = warp_latents(ramp()[None], np.full(GRID, Z), K, pose(tx), K[None], pose()[None],
                         np.full((1, *GRID), Z), HW)
        c = consistency_of(w.latent[None], w)
        assert c is not None and c.errors[0] == 0.0
        assert c.cells == int(w.valid.sum()) >= 2 * (GRID[1] - 2)


def test_a_shifted_target_scores_its_shift_and_grows_monotonically() -> None:
    errors = [score(ramp(s)) for s in (0, 1, 2, 3)]
    assert errors[0] == 0.0
    np.testing.assert_allclose(errors, [SLOPE * s for s in (0, 1, 2, 3)], rtol=1e-12)
    assert all(a < b for a, b in itertools.pairwise(errors))


def test_a_target_camera_moved_off_the_truth_scores_monotonically() -> None:
    """The candidate is the true view (the source itself, identity pose); the declared target
    pose moves right by whole cells: the reprojection reads s cells further right."""
    cell_m = (HW[1] / GRID[1]) * Z / K[0, 0]
    errors = [score(ramp(), s * cell_m) for s in (0, 1, 2, 3)]
    np.testing.assert_allclose(errors, [SLOPE * s for s in (0, 1, 2, 3)], atol=1e-12)


def test_a_constant_offset_scores_its_magnitude() -> None:
    for c in (-2.0, 0.5, 3.0):
        assert score(ramp() + c) == pytest.approx(abs(c), rel=1e-12)


def test_no_filled_cell_has_no_score() -> None:
    none = reprojection_consistency(ramp()[None], ramp()[None], np.zeros(GRID), K, pose(),
                                    K[None], pose()[None], np.zeros((1, *GRID)), HW)
    assert none is None
    behind = pose()
    behind[2, 3] = 2 * Z  # the source camera is past the plane: nothing in front of it
    assert reprojection_consistency(ramp()[None], ramp()[None], np.full(GRID, Z), K, pose(),
                                    K[None], behind[None], np.full((1, *GRID), Z), HW) is None


def test_masked_rms_refuses_an_empty_mask_and_bad_shapes() -> None:
    with pytest.raises(ValueError, match="no cell"):
        masked_rms(ramp()[None], ramp(), np.zeros(GRID, bool))
    with pytest.raises(ValueError, match="must be"):
        masked_rms(ramp(), ramp(), np.ones(GRID, bool))


def test_only_filled_cells_count() -> None:
    valid = np.zeros(GRID, bool)
    valid[0, :2] = True
    w = Warp(ramp(), valid, np.where(valid, 0, -1).astype(np.int64))
    cand = ramp()
    cand[:, 1, :] += 100.0  # unfilled row: ignored
    cand[:, 0, 0] += 2.0  # one of 2 filled cells off by 2 in every channel
    c = consistency_of(cand[None], w)
    assert c is not None and c.cells == 2
    assert c.errors[0] == pytest.approx(np.sqrt(2.0))


@settings(max_examples=60, deadline=None)
@given(st.floats(-1e6, 1e6), st.integers(0, 2**31 - 1), st.integers(1, 4))
def test_error_is_the_rms_of_the_difference_at_any_scale(scale: float, seed: int,
                                                         n: int) -> None:
    rng = np.random.default_rng(seed)
    ref = rng.normal(size=(3, *GRID)) * scale
    valid = rng.random(GRID) < 0.5
    valid[0, 0] = True
    d = rng.normal(size=(n, 3, *GRID)) * scale
    c = consistency_of(ref[None] + d, Warp(ref, valid, np.zeros(GRID, np.int64)))
    assert c is not None and np.isfinite(c.errors).all() and (c.errors >= 0).all()
    want = np.sqrt(np.mean(((ref[None] + d) - ref[None])[:, :, valid] ** 2, axis=(1, 2)))
    np.testing.assert_allclose(c.errors, want, rtol=1e-9, atol=0)
