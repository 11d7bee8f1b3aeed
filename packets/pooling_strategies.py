"""Alternative per-cell mean reductions, kept for the benchmark and as cross-checks.

Each takes a torch (N, C) feature view, in-frustum rows point_idx (M,), cells cell (M,) and returns
(n_cells, C) torch means (empty cells zero). None beats `pooling.sparse_mean_torch` here; see
docs/benchmarks_packets.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
import torch

from schemas.errors import DataError

I64 = npt.NDArray[np.int64]


def _numpy(t: torch.Tensor) -> npt.NDArray[Any]:
    """numpy view of t (float16/bfloat16 are upcast to float32: a copy)."""
    if t.dtype in (torch.float16, torch.bfloat16):
        t = t.float()
    arr: npt.NDArray[Any] = t.numpy()
    return arr


def scipy_csr_mean(arr: npt.NDArray[Any], idx: I64, cell: I64, n_cells: int) -> npt.NDArray[Any]:
    """Mean via a scipy CSR cell-by-point matrix (rows = cells, columns = sweep points)."""
    n = np.bincount(cell, minlength=n_cells)
    order = np.argsort(cell, kind="stable")
    indptr = np.zeros(n_cells + 1, dtype=np.int64)
    np.cumsum(n, out=indptr[1:])
    data = (1.0 / n[cell[order]]).astype(arr.dtype)
    A = sp.csr_matrix((data, idx[order], indptr), shape=(n_cells, arr.shape[0]))
    out: npt.NDArray[Any] = np.asarray(A @ arr)
    return out


def index_add_mean(t: torch.Tensor, idx: I64, cell: I64, n_cells: int) -> torch.Tensor:
    """Mean via torch gather + `index_add_` scatter, then division by the counts."""
    cell_t = torch.from_numpy(cell)
    out = torch.zeros((n_cells, t.shape[1]), dtype=t.dtype)
    out.index_add_(0, cell_t, t[torch.from_numpy(idx)])
    n = torch.bincount(cell_t, minlength=n_cells).clamp(min=1).to(t.dtype)
    return out / n[:, None]


def add_at_mean(arr: npt.NDArray[Any], idx: I64, cell: I64, n_cells: int) -> npt.NDArray[Any]:
    """Mean via numpy gather + unbuffered `np.add.at` scatter."""
    out = np.zeros((n_cells, arr.shape[1]), dtype=arr.dtype)
    np.add.at(out, cell, arr[idx])
    n = np.maximum(np.bincount(cell, minlength=n_cells), 1).astype(arr.dtype)
    result: npt.NDArray[Any] = out / n[:, None]
    return result


def reduceat_mean(arr: npt.NDArray[Any], idx: I64, cell: I64, n_cells: int) -> npt.NDArray[Any]:
    """Mean via sorting by cell, gathering in that order and `np.add.reduceat` segments."""
    n = np.bincount(cell, minlength=n_cells)
    out = np.zeros((n_cells, arr.shape[1]), dtype=arr.dtype)
    occ = np.flatnonzero(n)
    if occ.size == 0:
        return out
    order = np.argsort(cell, kind="stable")
    starts = (np.cumsum(n) - n)[occ]
    sums = np.add.reduceat(arr[idx[order]], starts, axis=0)
    out[occ] = sums / n[occ, None].astype(arr.dtype)
    return out


def pool_mean_alt(t: torch.Tensor, idx: I64, cell: I64, n_cells: int, method: str) -> torch.Tensor:
    """Dispatch to one alternative strategy by name; returns (n_cells, C) torch."""
    if method == "torch_index_add":
        if t.dtype in (torch.float16, torch.bfloat16):
            t = t[torch.from_numpy(idx)].float()
            idx = np.arange(idx.size, dtype=np.int64)
        return index_add_mean(t, idx, cell, n_cells)
    numpy_fns = {
        "scipy_csr": scipy_csr_mean,
        "numpy_add_at": add_at_mean,
        "numpy_reduceat": reduceat_mean,
    }
    if method not in numpy_fns:
        raise DataError(f"unknown pooling method {method!r}")
    return torch.from_numpy(numpy_fns[method](_numpy(t), idx, cell, n_cells))
