"""Per-cell depth statistics and the six explicit packet channels g (eq. 9).

Statistics are computed in float64 with a shifted two-pass scheme: every cell's depths are first
shifted by one of the cell's own depths (exact for constant cells), the mean is formed from the
shifted sum, and the variance from squared deviations about that mean with the compensating
term of Chan et al. (sum of deviations)^2 / n. Variance is the population variance (ddof = 0),
clamped at 0, and exactly 0 when all depths of a cell are equal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets._checks import require_finite, require_finite_scalar
from schemas import channels as _channels
from schemas.errors import DataError

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]

CHANNELS: tuple[str, ...] = _channels.CHANNELS
"""Names of the explicit channels (re-exported from schemas.channels, the one table)."""

N_EXPLICIT: int = _channels.N_G
"""Import-time count of the explicit channels (re-exported; `schemas.channels.n_g()`)."""


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


def explicit_channels(stats: CellStats, delta_tau_s: float | F64,
                      grid_hw: tuple[int, int]) -> F32:
    """g (n_g, H, W) float32, one row per schemas.channels.PACKET_CHANNELS (eq. 9).

    delta_tau_s: the view's delta tau (s), or (H*W,) one per cell (merged LiDARs).

    Occupied cells need a positive mean depth; empty cells are zero in every channel. Raises
    ValueError if a channel would not be finite in float32 (e.g. depth variance > 3.4e38 m^2).
    """
    occ = stats.n > 0
    if np.ndim(delta_tau_s) == 0:
        dt: float | F64 = require_finite_scalar("delta_tau_s", float(delta_tau_s))
    else:
        cells = np.asarray(delta_tau_s, dtype=np.float64)
        if cells.shape != stats.n.shape:
            raise DataError(f"per-cell delta tau has shape {cells.shape}, expected "
                            f"{stats.n.shape}")
        require_finite("delta_tau_s", cells)
        dt = cells[occ]
    if np.any(stats.mean[occ] <= 0):
        raise DataError("occupied cells need a positive mean depth (eq. 8: d_k > 0)")
    names = _channels.channel_names()
    g = np.zeros((len(names), stats.n.size))
    occupied = OccupiedCells(n=stats.n[occ].astype(np.float64), mean=stats.mean[occ],
                             var=stats.var[occ], delta_tau_s=dt)
    for k, name in enumerate(names):
        g[k, occ] = FORMULAS[name](occupied)
    with np.errstate(over="ignore"):
        out = g.astype(np.float32).reshape(len(names), *grid_hw)
    for k, name in enumerate(names):
        require_finite(f"explicit channel {name}", out[k])
    return out


@dataclass(frozen=True)
class OccupiedCells:
    """The occupied cells' support size n, mean depth (m), depth variance (m^2), each (K,)
    float64, and the packet's delta tau (s; (K,) per cell when LiDARs are merged): what the
    channel formulas read."""

    n: F64
    mean: F64
    var: F64
    delta_tau_s: float | F64


FORMULAS: dict[str, Callable[[OccupiedCells], F64 | float]] = {
    "validity": lambda c: 1.0,
    "log1p_mean_depth": lambda c: np.log1p(c.mean),
    "inv_mean_depth": lambda c: 1.0 / c.mean,
    "log1p_count": lambda c: np.log1p(c.n),
    "depth_variance": lambda c: c.var,
    "delta_tau_s": lambda c: c.delta_tau_s,
}
"""Each channel of schemas.channels.PACKET_CHANNELS as float64 values on the occupied cells
(eq. 9); `explicit_channels` writes them in the table's order."""
