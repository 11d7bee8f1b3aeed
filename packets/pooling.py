"""Pooled learned descriptors h (eq. 10): per-cell mean of per-point features, one pass.

The sweep's feature array (N, C_u) is computed once per sweep and shared by every view; a view
only brings its support sets (in-frustum row indices and their cells). The default reduction is a
sparse cell-by-point matrix A (n_cells x N, A[q, k] = 1/n_q for k in S_q) times the feature array,
done by `torch.sparse.mm` on a COO matrix: it reads only the in-frustum rows and never
materializes the gather `feat[idx]`. numpy inputs go through torch zero-copy and come back as
numpy. Alternatives that were measured live in `packets.pooling_strategies`.

Accuracy: a cell's points are summed in segments of at most `SEGMENT_POINTS` (each a row of the
sparse matrix) and the segment sums are combined in float64, so the float32 rounding error of a
mean stays below ~(SEGMENT_POINTS + 2) eps32 * mean|x| even with 10^6 points in one cell (plain
sequential float32 summation is off by ~1% there).

Dtypes: float32 features (the encoders' output dtype) are reduced in float32, float64 in float64;
float16/bfloat16 rows are gathered and upcast to float32 first (half accumulation is both slow on
CPU and inexact), in cache-sized blocks of whole cells (`_half_mean`: ~1.5x the float16 gather
floor instead of ~4x, bit-identical to gathering everything first). Empty cells are zero.
"""

from __future__ import annotations

from typing import Any, Literal, TypeVar

import numpy as np
import numpy.typing as npt
import torch

from packets.support import SupportSets
from schemas.errors import DataError

I64 = npt.NDArray[np.int64]
FeatArray = TypeVar("FeatArray", npt.NDArray[Any], torch.Tensor)

PoolMethod = Literal["sparse_mm", "scipy_csr", "torch_index_add", "numpy_add_at", "numpy_reduceat"]
DEFAULT_METHOD: PoolMethod = "sparse_mm"

_LOW_PRECISION = (torch.float16, torch.bfloat16)
SEGMENT_POINTS: int = 256
"""Most points summed sequentially in the feature dtype before a float64 combination."""


def _as_torch(feat: npt.NDArray[Any] | torch.Tensor) -> torch.Tensor:
    """Zero-copy torch view of a numpy or torch (N, C) feature array."""
    t = feat if isinstance(feat, torch.Tensor) else torch.from_numpy(np.asarray(feat))
    if t.ndim != 2:
        raise DataError(f"features must be (N, C), got shape {tuple(t.shape)}")
    if not (t.is_floating_point()):
        raise DataError(f"features must be floating point, got {t.dtype}")
    return t


def _weights(cell: I64, n_cells: int) -> npt.NDArray[np.float64]:
    """(M,) float64 weight 1/n_q of every supporting point."""
    n = np.bincount(cell, minlength=n_cells)
    return 1.0 / n[cell]


def segment_rows(cell: I64, n_cells: int) -> tuple[I64, I64 | None, int]:
    """Split cells holding more than SEGMENT_POINTS points into several matrix rows.

    Returns (row (M,) int64 per point, row_cell (n_rows,) int64 or None if rows == cells, n_rows).
    """
    n = np.bincount(cell, minlength=n_cells)
    if n.max(initial=0) <= SEGMENT_POINTS:
        return cell, None, n_cells
    order = np.argsort(cell, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size) - (np.cumsum(n) - n)[cell[order]]
    n_seg = -(-n // SEGMENT_POINTS)
    row = (np.cumsum(n_seg) - n_seg)[cell] + rank // SEGMENT_POINTS
    return row, np.repeat(np.arange(n_cells, dtype=np.int64), n_seg), int(n_seg.sum())


def sparse_mean_torch(feat: torch.Tensor, point_idx: I64, cell: I64, n_cells: int) -> torch.Tensor:
    """(n_cells, C) mean of feat rows point_idx per cell via a COO sparse matrix product."""
    if feat.dtype in _LOW_PRECISION and feat.requires_grad:  # differentiable: whole gather
        rows = feat.index_select(0, torch.from_numpy(point_idx)).float()
        return sparse_mean_torch(rows, np.arange(point_idx.size), cell, n_cells)
    if feat.dtype in _LOW_PRECISION:
        return _half_mean(feat, point_idx, cell, n_cells)
    row, row_cell, n_rows = segment_rows(cell, n_cells)
    indices = torch.from_numpy(np.stack([row, point_idx]))
    values = torch.from_numpy(_weights(cell, n_cells)).to(feat.dtype)
    A = torch.sparse_coo_tensor(
        indices, values, size=(n_rows, feat.shape[0]), check_invariants=False
    )
    out: torch.Tensor = torch.sparse.mm(A, feat)
    return _combine_segments(out, row_cell, n_cells)


def _combine_segments(out: torch.Tensor, row_cell: I64 | None, n_cells: int) -> torch.Tensor:
    """(n_cells, C) from the (n_rows, C) matrix-row sums: segments of a cell added in float64."""
    if row_cell is None:
        return out
    total = torch.zeros((n_cells, out.shape[1]), dtype=torch.float64)
    total.index_add_(0, torch.from_numpy(row_cell), out.double())
    return total.to(out.dtype)


HALF_BLOCK_POINTS = 128
"""Points per block of the float16/bfloat16 path: their float32 copy (0.6 MB at C_u 1224)
stays in the CPU cache between the cast and the product."""


def _half_blocks(row: I64, n_rows: int) -> list[tuple[int, int, int, int]]:
    """Blocks (row_start, row_stop, point_start, point_stop) of whole matrix rows, about
    HALF_BLOCK_POINTS points each, over points sorted by row."""
    counts = np.bincount(row, minlength=n_rows)
    stops = np.cumsum(counts)
    starts = stops - counts
    block = starts // HALF_BLOCK_POINTS  # non-decreasing: each block is a run of rows
    cuts = np.flatnonzero(np.diff(block)) + 1
    firsts = np.concatenate([[0], cuts])
    lasts = np.concatenate([cuts, [n_rows]])
    return [(int(a), int(b), int(starts[a]), int(stops[b - 1]))
            for a, b in zip(firsts, lasts, strict=True) if b > a]


def _half_mean(feat: torch.Tensor, point_idx: I64, cell: I64, n_cells: int) -> torch.Tensor:
    """`sparse_mean_torch` of float16/bfloat16 features, bit-identical to gathering every
    row as float32 and taking the one sparse product, but in cache-sized blocks of whole
    matrix rows: each block's rows are gathered, cast into a reused float32 buffer and
    multiplied while still in cache (one pass over the in-frustum rows instead of three).

    Identical because a row's products are accumulated in the same order: points are taken
    in a stable sort by row, so within a row they keep their order in `point_idx`.
    """
    row, row_cell, n_rows = segment_rows(cell, n_cells)
    order = np.argsort(row, kind="stable")
    src = torch.from_numpy(point_idx[order])
    row_sorted = row[order]
    weights = torch.from_numpy(_weights(cell, n_cells)[order]).to(torch.float32)
    width = feat.shape[1]
    out = torch.zeros((n_rows, width), dtype=torch.float32)
    blocks = _half_blocks(row, n_rows)
    most = max((p1 - p0 for _, _, p0, p1 in blocks), default=0)
    low = torch.empty((most, width), dtype=feat.dtype)
    high = torch.empty((most, width), dtype=torch.float32)
    # COO indices of every block at once: (row within its block, point within its block)
    first_row = np.repeat([r0 for r0, _, p0, p1 in blocks], [p1 - p0 for _, _, p0, p1 in blocks])
    first_point = np.repeat([p0 for _, _, p0, p1 in blocks], [p1 - p0 for _, _, p0, p1 in blocks])
    local = torch.from_numpy(np.stack([row_sorted - first_row,
                                       np.arange(row_sorted.size) - first_point]))
    for r0, r1, p0, p1 in blocks:
        n = p1 - p0
        if n == 0:
            continue
        torch.index_select(feat, 0, src[p0:p1], out=low[:n])
        high[:n].copy_(low[:n])
        A = torch.sparse_coo_tensor(local[:, p0:p1], weights[p0:p1], size=(r1 - r0, n),
                                    check_invariants=False, is_coalesced=True)
        out[r0:r1] = torch.sparse.mm(A, high[:n])
    return _combine_segments(out, row_cell, n_cells)


def pool_mean(
    feat: FeatArray,
    point_idx: I64,
    cell: I64,
    n_cells: int,
    method: PoolMethod = DEFAULT_METHOD,
) -> FeatArray:
    """(n_cells, C) per-cell mean of the feat (N, C) rows `point_idx` (M,) in cells `cell` (M,).

    Returns the input's kind (numpy or torch); float32 for float16/bfloat16/float32 input.
    """
    idx = np.asarray(point_idx, dtype=np.int64)
    cel = np.asarray(cell, dtype=np.int64)
    if idx.shape != cel.shape or idx.ndim != 1:
        raise DataError(f"point_idx {idx.shape} and cell {cel.shape} must be equal 1-D shapes")
    t = _as_torch(feat)
    if idx.size and (idx.min() < 0 or idx.max() >= t.shape[0]):
        raise DataError(f"point_idx must lie in [0, {t.shape[0]}), got [{idx.min()}, {idx.max()}]")
    if method == "sparse_mm":
        out = sparse_mean_torch(t, idx, cel, n_cells)
    else:
        from packets import pooling_strategies

        out = pooling_strategies.pool_mean_alt(t, idx, cel, n_cells, method)
    if isinstance(feat, torch.Tensor):
        return out
    result: npt.NDArray[Any] = out.numpy()
    return result


def pool_support(
    feat: FeatArray, sup: SupportSets, method: PoolMethod = DEFAULT_METHOD
) -> FeatArray:
    """h (C, H, W): pooled descriptors of one view on its latent grid (same kind as feat).

    A view, not a copy, of the pooled cell rows (H*W, C): the memory stays cell-major, so a
    consumer wanting rows (the cache's packed h_cells) takes them without a transpose.
    """
    pooled = pool_mean(feat, sup.point_idx, sup.cell, sup.n_cells, method)
    h, w = sup.grid_hw
    if isinstance(pooled, torch.Tensor):
        return pooled.T.reshape(-1, h, w)
    chw: npt.NDArray[Any] = pooled.T.reshape(-1, h, w)
    return chw
