"""Packet depth against ground truth: per-cell reference depth, border cells and error metrics.

Pure math on arrays. The reference of a latent cell is the visible surface: the median of the
ground-truth depths (metres along the optical axis) of its `patch` x `patch` pixels, with their
spread (90th minus 10th percentile). Pixels without a surface (sky, depth 0) are ignored; a cell
needs at least half of its pixels on a surface to have a reference.

A cell is a *border* cell when a depth discontinuity runs through it or along its edge: two
4-adjacent pixels of the cell (or one of its pixels and its neighbour across the cell edge)
differ by more than `EDGE_REL_JUMP` of the nearer depth, or one has a surface and the other not.
Other cells with a reference are *interior* cells.

Metrics over cells with a packet depth d and a reference d*: abs-rel = mean |d - d*| / d*,
RMSE = sqrt(mean (d - d*)^2) in metres, delta<t = share of cells with max(d/d*, d*/d) < t.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.channels import INV_MEAN_DEPTH, VALIDITY, channel_index, n_g
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]

EDGE_REL_JUMP: float = 0.05
"""Relative depth step between adjacent pixels that counts as a discontinuity (5 %)."""
MIN_SURFACE_SHARE: float = 0.5
"""A cell needs this share of its pixels on a surface to have a reference depth."""
DELTAS: tuple[float, ...] = (1.05, 1.25)


@dataclass(frozen=True)
class CellReference:
    """Ground truth on the (H, W) latent grid: median depth (m, NaN without a reference),
    spread p90 - p10 (m, NaN likewise) and border flag (bool)."""

    median: F64
    spread: F64
    border: Bool

    @property
    def valid(self) -> Bool:
        """(H, W) cells with a reference depth."""
        out: Bool = np.isfinite(self.median)
        return out


def _pixel_edges(depth: F64) -> Bool:
    """(Hi, Wi) pixels on a depth discontinuity with one of their 4 neighbours."""
    hit = depth > 0
    edge = np.zeros(depth.shape, dtype=bool)
    for axis in (0, 1):
        a = np.moveaxis(depth, axis, 0)
        ha = np.moveaxis(hit, axis, 0)
        near = np.minimum(a[1:], a[:-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            jump = np.abs(a[1:] - a[:-1]) > EDGE_REL_JUMP * near
        step = (ha[1:] != ha[:-1]) | (ha[1:] & ha[:-1] & jump)
        e = np.moveaxis(edge, axis, 0)
        e[1:] |= step
        e[:-1] |= step
    return edge


def cell_reference(depth: npt.ArrayLike, patch: int) -> CellReference:
    """Reference depth of every latent cell from a ground-truth depth map (Hi, Wi) in metres.

    Hi and Wi must be multiples of `patch`; non-finite or non-positive depths mean no surface.
    """
    d = np.asarray(depth, dtype=np.float64)
    if patch <= 0 or d.ndim != 2 or d.shape[0] % patch or d.shape[1] % patch:
        raise DataError(f"depth map {d.shape} must be 2-D with sides multiple of {patch}")
    d = np.where(np.isfinite(d) & (d > 0), d, 0.0)
    h, w = d.shape[0] // patch, d.shape[1] // patch

    def cells(a: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
        return a.reshape(h, patch, w, patch).swapaxes(1, 2).reshape(h, w, patch * patch)

    px = cells(np.where(d > 0, d, np.nan))
    share = np.mean(np.isfinite(px), axis=2)
    ok = share >= MIN_SURFACE_SHARE
    median = np.full((h, w), np.nan)
    spread = np.full((h, w), np.nan)
    if ok.any():
        sel = px[ok]
        median[ok] = np.nanmedian(sel, axis=1)
        p10, p90 = np.nanpercentile(sel, [10.0, 90.0], axis=1)
        spread[ok] = p90 - p10
    border = np.any(cells(_pixel_edges(d)), axis=2) & ok
    return CellReference(median, spread, border)


def packet_depth(g: npt.ArrayLike) -> F64:
    """(H, W) cell mean depth in metres from packet g (n_g, H, W): 1 / (the inverse mean
    depth channel), NaN on empty cells."""
    arr = np.asarray(g, dtype=np.float64)
    valid, inv = channel_index(VALIDITY), channel_index(INV_MEAN_DEPTH)
    if arr.ndim != 3 or arr.shape[0] <= max(valid, inv):
        raise DataError(f"g must be ({n_g()}, H, W), got shape {arr.shape}")
    occ = (arr[valid] > 0) & (arr[inv] > 0)
    out = np.full(arr.shape[1:], np.nan)
    out[occ] = 1.0 / arr[inv][occ]
    return out


@dataclass(frozen=True)
class DepthErrors:
    """Error summary of n cells: abs-rel, RMSE (m), share within each of DELTAS."""

    n: int
    abs_rel: float
    rmse_m: float
    delta: dict[float, float]

    def as_dict(self, prefix: str = "") -> dict[str, float | int]:
        """Flat JSON-ready keys: n, abs_rel, rmse_m, delta_1.05, delta_1.25 (NaN when n = 0)."""
        out: dict[str, float | int] = {f"{prefix}n": self.n, f"{prefix}abs_rel": self.abs_rel,
                                       f"{prefix}rmse_m": self.rmse_m}
        out.update({f"{prefix}delta_{t:g}": v for t, v in self.delta.items()})
        return out


def depth_errors(pred: npt.ArrayLike, ref: npt.ArrayLike) -> DepthErrors:
    """Errors of predicted depths (n,) against reference depths (n,), both metres > 0.

    Pairs where either is not finite are left out. n = 0 gives NaN metrics.
    """
    p = np.asarray(pred, dtype=np.float64).ravel()
    r = np.asarray(ref, dtype=np.float64).ravel()
    if p.shape != r.shape:
        raise DataError(f"pred {p.shape} and ref {r.shape} must have the same size")
    ok = np.isfinite(p) & np.isfinite(r) & (r > 0) & (p > 0)
    p, r = p[ok], r[ok]
    if p.size == 0:
        return DepthErrors(0, float("nan"), float("nan"), {t: float("nan") for t in DELTAS})
    ratio = np.maximum(p / r, r / p)
    return DepthErrors(
        n=int(p.size),
        abs_rel=float(np.mean(np.abs(p - r) / r)),
        rmse_m=float(np.sqrt(np.mean((p - r) ** 2))),
        delta={t: float(np.mean(ratio < t)) for t in DELTAS},
    )


def abs_rel(pred: npt.ArrayLike, ref: npt.ArrayLike) -> F64:
    """Per-cell |pred - ref| / ref (same shape; NaN where either is missing)."""
    p = np.asarray(pred, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        out: F64 = np.where((r > 0) & (p > 0), np.abs(p - r) / r, np.nan)
    return out


def slope(x: npt.ArrayLike, y: npt.ArrayLike) -> float:
    """Least-squares slope of y on x (with intercept) over finite pairs; NaN with < 2 x values."""
    a = np.asarray(x, dtype=np.float64).ravel()
    b = np.asarray(y, dtype=np.float64).ravel()
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size < 2 or np.ptp(a) == 0:
        return float("nan")
    ac = a - a.mean()
    return float(ac @ (b - b.mean()) / (ac @ ac))


def dtau_bins(abs_dtau_s: npt.ArrayLike, edges_s: tuple[float, ...]) -> npt.NDArray[np.int64]:
    """Bin index of each |Δτ| (s) in the half-open bins [edges[i], edges[i+1]); last bin open."""
    x = np.asarray(abs_dtau_s, dtype=np.float64)
    out: npt.NDArray[np.int64] = np.searchsorted(np.asarray(edges_s), x, side="right") - 1
    return out


def support_depth(cell: npt.ArrayLike, depth: npt.ArrayLike, grid_hw: tuple[int, int]) -> F64:
    """(H, W) mean depth (m) of support points per cell (NaN on empty cells), as g gives it
    (1 / inv_mean_depth).

    cell: (M,) flat cell ids; depth: (M,) camera depths in metres (a view's support sets).
    """
    from packets.statistics import cell_depth_stats

    h, w = grid_hw
    st = cell_depth_stats(np.asarray(cell, np.int64), np.asarray(depth, np.float64), h * w)
    out: F64 = np.where(st.n > 0, st.mean, np.nan).reshape(h, w)
    return out
