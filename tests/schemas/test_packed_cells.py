"""Packed packet features: pack and unpack are exact inverses on occupied cells."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.packed_cells import cell_counts, occupied_cells, pack_rows, unpack_rows


def _views(seed: int, n: int, c: int, h: int, w: int, p: float) -> tuple[np.ndarray, np.ndarray]:
    """Dense h (n, c, h, w) float16, zero off the occupied cells (n, h, w), and those cells."""
    rng = np.random.default_rng(seed)
    occupied = rng.random((n, h, w)) < p
    values = rng.normal(scale=100.0, size=(n, c, h, w)).astype(np.float16)
    return np.where(occupied[:, None], values, np.float16(0)), occupied


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4), c=st.integers(1, 9),
       h=st.integers(1, 5), w=st.integers(1, 6), p=st.sampled_from([0.0, 0.3, 1.0]))
def test_unpack_inverts_pack_at_every_occupancy(seed: int, n: int, c: int, h: int, w: int,
                                                p: float) -> None:
    dense, occupied = _views(seed, n, c, h, w, p)
    rows = pack_rows(dense, occupied)
    assert [len(r) for r in rows] == cell_counts(occupied).tolist()
    for v, r in enumerate(rows):  # row-major cell order
        np.testing.assert_array_equal(r, dense[v].reshape(c, -1)[:, occupied[v].ravel()].T)
    np.testing.assert_array_equal(unpack_rows(rows, occupied), np.moveaxis(dense, 1, -1))
    cell_major = np.moveaxis(np.ascontiguousarray(np.moveaxis(dense, 1, -1)), -1, 1)
    for a, b in zip(pack_rows(cell_major, occupied), rows, strict=True):  # pooling's layout
        np.testing.assert_array_equal(a, b)


def test_extreme_float16_values_survive() -> None:
    dense, occupied = _views(0, 2, 3, 4, 5, 0.5)
    dense[occupied[:, None].repeat(3, 1)] = np.float16(65504.0)  # float16 max
    dense[0, 0][occupied[0]] = np.float16(6e-8)  # smallest subnormal
    back = unpack_rows(pack_rows(dense, occupied), occupied)
    np.testing.assert_array_equal(back, np.moveaxis(dense, 1, -1))


def test_features_off_the_occupied_cells_refused_but_negative_zero_is_zero() -> None:
    dense, occupied = _views(1, 3, 4, 3, 3, 0.5)
    occupied[2, 0, 0] = False
    signed = dense.copy()
    signed[2, :, 0, 0] = np.float16(-0.0)
    assert len(pack_rows(signed, occupied)[2]) == occupied[2].sum()
    dense[2, 1, 0, 0] = 1.0
    with pytest.raises(ValueError, match="view 2: h has non-zero features on cells without"):
        pack_rows(dense, occupied)
    cell_major = np.moveaxis(np.ascontiguousarray(np.moveaxis(dense, 1, -1)), -1, 1)
    with pytest.raises(ValueError, match="view 2: h has non-zero features on cells without"):
        pack_rows(cell_major, occupied)


def test_row_counts_must_match_the_occupancy() -> None:
    dense, occupied = _views(2, 2, 3, 2, 2, 1.0)
    rows = pack_rows(dense, occupied)
    with pytest.raises(ValueError, match="view 1: 3 packed rows of width 3 for 4 occupied"):
        unpack_rows([rows[0], rows[1][:3]], occupied)
    with pytest.raises(ValueError, match="1 views of rows for 2 views"):
        unpack_rows(rows[:1], occupied)


def test_occupied_cells_read_the_validity_channel() -> None:
    g = np.zeros((2, 6, 2, 3), np.float32)
    g[1, 0, 1, 2] = 1.0
    g[0, 1] = 5.0  # other channels do not count
    np.testing.assert_array_equal(occupied_cells(g).sum(axis=(1, 2)), [0, 1])
    with pytest.raises(ValueError, match=r"g must be \(N, 6, H, W\)"):
        occupied_cells(g[0])
