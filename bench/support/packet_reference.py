"""Slow, obviously correct reference implementations (per point / per cell loops, float64).

For tests and the benchmark baseline only; never used by the pipeline.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from schemas.channels import n_g

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


def reference_project_point(
    p_cam: tuple[float, float, float], K: F64, model: str, D: F64
) -> tuple[float, float]:
    """Pixel (u, v) of one camera-frame point with z > 0, written out with the math module."""
    x, y = p_cam[0] / p_cam[2], p_cam[1] / p_cam[2]
    if model == "pinhole":
        k1, k2, p1, p2, k3 = (list(D) + [0.0] * 5)[:5]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    else:
        r = math.hypot(x, y)
        th = math.atan(r)
        th_d = th * (1 + D[0] * th**2 + D[1] * th**4 + D[2] * th**6 + D[3] * th**8)
        s = th_d / r if r > 0 else 1.0
        xd, yd = x * s, y * s
    return K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]


def reference_cell_stats(cell: I64, depth: F64, n_cells: int) -> tuple[I64, F64, F64]:
    """Per-cell (n, mean, population variance) with a mask per cell and exact `math.fsum`."""
    n = np.zeros(n_cells, dtype=np.int64)
    mean = np.zeros(n_cells)
    var = np.zeros(n_cells)
    for q in range(n_cells):
        d = [float(v) for v in depth[cell == q]]
        if not d:
            continue
        n[q] = len(d)
        mean[q] = d[0] + math.fsum(v - d[0] for v in d) / len(d)
        var[q] = math.fsum((v - mean[q]) ** 2 for v in d) / len(d)
    return n, mean, var


def reference_pool_mean(feat: npt.NDArray[Any], point_idx: I64, cell: I64, n_cells: int) -> F64:
    """(n_cells, C) float64 per-cell mean of feature rows: one boolean mask per cell.

    This is the loop a researcher would write first; the benchmark's slow baseline.
    """
    out = np.zeros((n_cells, feat.shape[1]))
    for q in range(n_cells):
        mask = cell == q
        if mask.any():
            out[q] = feat[point_idx[mask]].astype(np.float64).mean(axis=0)
    return out


def reference_explicit(
    n: I64, mean: F64, var: F64, delta_tau_s: float, grid_hw: tuple[int, int]
) -> F64:
    """(n_g, H, W) float64 eq. 9 channels, one cell at a time (written out independently of
    packets.statistics; a channel table of another width fails here, as it should)."""
    g = np.zeros((n_g(), n.size))
    for q in range(n.size):
        if n[q] > 0:
            g[:, q] = [
                1.0,
                math.log1p(mean[q]),
                1.0 / mean[q],
                math.log1p(n[q]),
                var[q],
                delta_tau_s,
            ]
    return g.reshape(n_g(), *grid_hw)
