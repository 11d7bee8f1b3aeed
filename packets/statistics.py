"""Per-cell depth statistics and the six explicit packet channels g (eq. 9).

Statistics are computed in float64 with a shifted two-pass scheme: every cell's depths are first
shifted by one of the cell's own depths (exact for constant cells), the mean is formed from the
shifted sum, and the variance from squared deviations about that mean with the compensating
term of Chan et al. (sum of deviations)^2 / n. Variance is the population variance (ddof = 0),
clamped at 0, and exactly 0 when all depths of a cell are equal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets._checks import require_finite, require_finite_scalar
from schemas.errors import DataError

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]

CHANNELS: tuple[str, ...] = (
    "validity",
    "log1p_mean_depth",
    "inv_mean_depth",
    "log1p_count",
    "depth_variance",
    "delta_tau_s",
)
"""Names of the explicit channels, in eq. 9 order (units: -, log m, 1/m, -, m^2, s)."""

N_EXPLICIT: int = len(CHANNELS)


@dataclass(frozen=True)
class CellStats:
    """Per-cell support size n (n_cells,) int64, mean depth (m) and depth variance (m^2), float64.

    Empty cells carry n = 0, mean = 0, var = 0.
    """

    n: I64
    mean: F64
    var: F64


def cell_depth_stats(cell: I64, depth: F64, n_cells: int) -> CellStats:
    """Count, mean and variance of depth (M,) metres per cell id (M,) in [0, n_cells)."""
    d = np.asarray(depth, dtype=np.float64)
    c = np.asarray(cell, dtype=np.int64)
    require_finite("depth", d)
    if d.shape != c.shape or d.ndim != 1:
        raise DataError(f"cell {c.shape} and depth {d.shape} must be equal 1-D shapes")
    if c.size and (c.min() < 0 or c.max() >= n_cells):
        raise DataError(f"cell ids must lie in [0, {n_cells}), got [{c.min()}, {c.max()}]")
    n = np.bincount(c, minlength=n_cells).astype(np.int64)
    occ = n > 0
    shift = np.zeros(n_cells)
    shift[c] = d  # any one depth of each cell: an exact shift, so constant cells stay exact
    x = d - shift[c]
    mean = shift.copy()
    mean[occ] += np.bincount(c, weights=x, minlength=n_cells)[occ] / n[occ]
    dev = d - mean[c]
    s1 = np.bincount(c, weights=dev, minlength=n_cells)
    s2 = np.bincount(c, weights=dev * dev, minlength=n_cells)
    var = np.zeros(n_cells)
    var[occ] = np.maximum((s2[occ] - s1[occ] * s1[occ] / n[occ]) / n[occ], 0.0)
    return CellStats(n=n, mean=mean, var=var)


def explicit_channels(stats: CellStats, delta_tau_s: float, grid_hw: tuple[int, int]) -> F32:
    """g (6, H, W) float32: [valid, log(1+mean), 1/mean, log(1+n), var, delta_tau] (eq. 9).

    Occupied cells need a positive mean depth; empty cells are zero in every channel. Raises
    ValueError if a channel would not be finite in float32 (e.g. depth variance > 3.4e38 m^2).
    """
    dt = require_finite_scalar("delta_tau_s", delta_tau_s)
    occ = stats.n > 0
    if np.any(stats.mean[occ] <= 0):
        raise DataError("occupied cells need a positive mean depth (eq. 8: d_k > 0)")
    g = np.zeros((N_EXPLICIT, stats.n.size))
    m = stats.mean[occ]
    g[0, occ] = 1.0
    g[1, occ] = np.log1p(m)
    g[2, occ] = 1.0 / m
    g[3, occ] = np.log1p(stats.n[occ].astype(np.float64))
    g[4, occ] = stats.var[occ]
    g[5, occ] = dt
    with np.errstate(over="ignore"):
        out = g.astype(np.float32).reshape(N_EXPLICIT, *grid_hw)
    for k, name in enumerate(CHANNELS):
        require_finite(f"explicit channel {name}", out[k])
    return out
