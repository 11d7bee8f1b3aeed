"""Packet features stored for occupied cells only (cache format 2), as pure array math.

A view's packet features h (C_u, H, W) are zero on every cell without LiDAR support
(paper eq. 10), and most cells have none. The cache stores them packed as `h_cells`
(N, H*W, C_u): row r of view n holds the C_u features of the r-th occupied cell of view n,
cells taken in row-major (row, col) order, and every row after the last occupied cell is
zero (never written: absent chunks, see schemas.cache_layout.CELL_BLOCK). A cell is
occupied when its validity channel g[0] is 1 (eq. 9), so the geometry g alone says how
many rows a view has and where each belongs. Reading needs no transpose: rows unpack to
channels-last cells (H, W, C_u) with one contiguous copy each.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from schemas.channels import VALIDITY, channel_index, n_g
from schemas.errors import DataError

VALID_CHANNEL = channel_index(VALIDITY)
"""Index of the validity channel m in g (1.0 on occupied cells, 0.0 elsewhere); import-time
snapshot of `schemas.channels.channel_index(VALIDITY)`."""


def occupied_cells(g: NDArray[Any]) -> NDArray[np.bool_]:
    """Occupied cells (N, H, W) bool of packet geometry g (N, n_g, H, W): validity > 0.5."""
    if g.ndim != 4:
        raise DataError(f"g must be (N, {n_g()}, H, W), got shape {g.shape}")
    return np.asarray(g[:, channel_index(VALIDITY)] > 0.5)


def pack_rows(h: NDArray[Any], occupied: NDArray[np.bool_]) -> list[NDArray[Any]]:
    """Each view's packed rows (k_n, C_u) of dense h (N, C_u, H, W) on `occupied` (N, H, W).

    Rows follow the row-major order of the occupied cells; same dtype as h (views into one
    buffer of the occupied rows only). Raises ValueError naming the view when h is non-zero
    on a cell that is not occupied (those values would be lost: eq. 10 makes them zero).
    """
    n, c, height, width = h.shape
    if occupied.shape != (n, height, width):
        raise DataError(f"occupied cells {occupied.shape} do not match h {h.shape}")
    counts = cell_counts(occupied)
    buffer = np.empty((int(counts.sum()), c), h.dtype)
    rows = np.split(buffer, np.cumsum(counts)[:-1]) if n else []
    for v in range(n):
        mask = occupied[v].ravel()
        rows[v][:] = _take_cells(h[v], mask)
        lost = _nonzero_words(h[v]) != _nonzero_words(rows[v])  # fast; -0.0 counts
        if lost and np.any(_take_cells(h[v], ~mask) != 0):  # exact
            raise DataError(f"view {v}: h has non-zero features on cells without support "
                             "(g[0] == 0); packets must be zero there (eq. 10)")
    return rows


def _take_cells(view: NDArray[Any], mask: NDArray[np.bool_]) -> NDArray[Any]:
    """Rows (k, C_u) of the cells `mask` (H*W,) of one view (C_u, H, W), row-major order.

    Gathers whole rows when the view's memory is cell-major (as pooling leaves it), else
    columns with one transposing copy.
    """
    cell_major = np.moveaxis(view, 0, -1)
    if cell_major.flags.c_contiguous:
        return cell_major.reshape(mask.size, -1)[mask]
    return view.reshape(-1, mask.size)[:, mask].T


def _nonzero_words(x: NDArray[Any]) -> int:
    """Count of elements whose bits are not all zero (-0.0 counts): fast for float16 too.
    Reads `x` in its memory order (no copy for C- or F-ordered views of one buffer)."""
    words = np.ravel(x, order="K")
    return int(np.count_nonzero(words.view(f"u{words.dtype.itemsize}")))


def cell_counts(occupied: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Packed rows per view (N,) int64: the occupied cells of each view (N, H, W)."""
    return np.asarray(occupied.reshape(len(occupied), -1).sum(axis=1), np.int64)


def unpack_rows(rows: list[NDArray[Any]], occupied: NDArray[np.bool_]) -> NDArray[Any]:
    """Dense channels-last features (N, H, W, C_u) from each view's packed rows (k_n, C_u).

    `occupied` (N, H, W) must be the occupancy the rows were packed with (from the same
    views' g); unoccupied cells are zero. Raises ValueError naming the view when its row
    count is not its number of occupied cells (g and h disagree).
    """
    if len(rows) != len(occupied) or not rows:
        raise DataError(f"{len(rows)} views of rows for {len(occupied)} views of occupancy")
    c = rows[0].shape[1]
    for v, (view_rows, n) in enumerate(zip(rows, cell_counts(occupied), strict=True)):
        if view_rows.shape != (n, c):
            raise DataError(f"view {v}: {view_rows.shape[0]} packed rows of width "
                             f"{view_rows.shape[1]} for {n} occupied cells of width {c}")
    return unpack_packed(np.concatenate(rows), occupied)


def unpack_packed(rows: NDArray[Any], occupied: NDArray[np.bool_]) -> NDArray[Any]:
    """Dense channels-last features (N, H, W, C_u) from all views' packed rows stacked view
    after view (sum_n k_n, C_u) (as `store.cache_io.read_clip` returns "h_rows").

    Raises DataError when the row count is not the number of occupied cells.
    """
    if rows.ndim != 2 or len(rows) != int(occupied.sum()):
        raise DataError(f"{rows.shape} packed rows for {int(occupied.sum())} occupied cells")
    out = np.zeros((*occupied.shape, rows.shape[1]), rows.dtype)
    out[occupied] = rows
    return out
