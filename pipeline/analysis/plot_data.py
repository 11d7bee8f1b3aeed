"""Array preparation for the plots: PCA pseudo-colour, occupancy frequency, record grouping.

Kept apart from `pipeline.analysis.plots` (which only draws) so the numbers behind each figure
can be tested without a renderer.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from schemas.errors import DataError

F64 = npt.NDArray[np.float64]

Records: TypeAlias = pa.Table | Sequence[Mapping[str, Any]]
"""Rows as a pyarrow Table or a sequence of dicts (e.g. a benchmark's result rows)."""


def _as_batch(features: npt.ArrayLike, mask: npt.ArrayLike) -> tuple[F64, npt.NDArray[np.bool_]]:
    """Features (V, C, H, W) float64 and mask (V, H, W) bool from single or batched inputs."""
    f = np.asarray(features, dtype=np.float64)
    m = np.asarray(mask, dtype=np.bool_)
    if f.ndim == 3:
        f = f[None]
        m = m[None] if m.ndim == 2 else m
    if f.ndim != 4 or m.shape != (f.shape[0], *f.shape[2:]):
        raise DataError(
            f"features must be (C,H,W) or (V,C,H,W) with mask (H,W)/(V,H,W); "
            f"got features {np.shape(features)}, mask {np.shape(mask)}"
        )
    if not np.isfinite(f[np.broadcast_to(m[:, None], f.shape)]).all():
        raise DataError("features have NaN/Inf on supported cells")
    return f, m


def pca_rgb(features: npt.ArrayLike, mask: npt.ArrayLike) -> F64:
    """PCA pseudo-colour of feature maps on their supported cells, like the paper's Fig. 4.

    features: (C, H, W) or (V, C, H, W) float features on the latent grid.
    mask: (H, W) or (V, H, W) bool, True on supported cells (n_q > 0).
    Returns (H, W, 3) or (V, H, W, 3) float64 RGB in [0, 1]. One 3-component PCA is fitted on
    the supported cells of all V views together (so colours agree across views); each component
    is signed so its largest-magnitude loading is positive (deterministic), and its scores are
    mapped to [0, 1] between their 1st and 99th percentiles. Unsupported cells are 0 (black);
    components beyond the data's rank stay 0.
    """
    f, m = _as_batch(features, mask)
    v, _, h, w = f.shape
    rgb = np.zeros((v, h, w, 3), dtype=np.float64)
    cells = np.moveaxis(f, 1, -1)[m]  # (N, C) supported cells of all views
    if cells.shape[0] >= 2:
        centred = cells - cells.mean(axis=0)
        _, s, vt = np.linalg.svd(centred, full_matrices=False)
        k = int(min(3, np.sum(s > s[0] * max(centred.shape) * np.finfo(np.float64).eps)))
        axes = vt[:k] * np.sign(vt[np.arange(k), np.argmax(np.abs(vt[:k]), axis=1)])[:, None]
        scores = centred @ axes.T  # (N, k)
        lo, hi = np.percentile(scores, [1.0, 99.0], axis=0)
        span = np.where(hi > lo, hi - lo, 1.0)
        colour = np.zeros((cells.shape[0], 3))
        colour[:, :k] = np.clip((scores - lo) / span, 0.0, 1.0)
        rgb[m] = colour
    return rgb[0] if np.ndim(features) == 3 else rgb


def occupancy_frequency(
    cells: pa.Table, grid_hw: tuple[int, int], n_views: int | None = None
) -> F64:
    """(H, W) float64 fraction of views in which each cell is supported (n > 0).

    cells: per-cell table with int columns row, col, n and the view key recording, camera, frame.
    n_views: number of views the table covers; default: distinct views present in `cells`
        (views with no supported cell are absent from a per-cell table, so pass the view count).
    """
    h, w = grid_hw
    occ = cells.filter(pc.greater(cells["n"], 0))
    rows = occ["row"].to_numpy().astype(np.int64)
    cols = occ["col"].to_numpy().astype(np.int64)
    if rows.size and (rows.min() < 0 or rows.max() >= h or cols.min() < 0 or cols.max() >= w):
        raise DataError(f"cell rows/cols outside the {grid_hw} grid")
    counts = np.zeros((h, w), dtype=np.float64)
    np.add.at(counts, (rows, cols), 1.0)
    if n_views is None:
        keys = occ.select(["recording", "camera", "frame"]).group_by(
            ["recording", "camera", "frame"]).aggregate([])
        n_views = keys.num_rows
    return counts / n_views if n_views > 0 else counts


def as_rows(records: Records) -> list[dict[str, Any]]:
    """Rows of a pyarrow Table or a sequence of mappings, as plain dicts."""
    if isinstance(records, pa.Table):
        rows: list[dict[str, Any]] = records.to_pylist()
        return rows
    return [dict(r) for r in records]


def series_by(
    rows: list[dict[str, Any]], group: str, x: str, y: str
) -> dict[Any, tuple[F64, F64]]:
    """Group rows by `group`; per group (x sorted, y) float64 arrays; rows missing y are skipped."""
    out: dict[Any, list[tuple[float, float]]] = {}
    for r in rows:
        if r.get(y) is None or r.get(x) is None:
            continue
        out.setdefault(r.get(group), []).append((float(r[x]), float(r[y])))
    series: dict[Any, tuple[F64, F64]] = {}
    for key in sorted(out, key=str):
        pts = np.array(sorted(out[key]), dtype=np.float64)
        series[key] = (pts[:, 0], pts[:, 1])
    return series


def dtau_groups(views: pa.Table, accepted: bool | None = None) -> dict[tuple[str, str], F64]:
    """Non-null dtau_s (seconds, float64) per (recording, camera), keys sorted.

    accepted: None = every view; True / False = only views whose `reject_reason` is null / set
    (a table without that column counts every view as accepted).
    """
    groups: dict[tuple[str, str], list[float]] = {}
    has_reason = "reject_reason" in views.column_names
    cols = ["recording", "camera", "dtau_s"] + (["reject_reason"] if has_reason else [])
    for r in views.select(cols).to_pylist():
        if accepted is not None and (r.get("reject_reason") is None) != accepted:
            continue
        if r["dtau_s"] is not None and np.isfinite(r["dtau_s"]):
            groups.setdefault((r["recording"], r["camera"]), []).append(float(r["dtau_s"]))
    return {k: np.asarray(groups[k], dtype=np.float64) for k in sorted(groups)}


ROTATION_AXES = ("roll", "pitch", "yaw")
"""Components of a camera rotation in the reprojection-consistency table (deg)."""
INJECTED_PREFIXES = ("injected_", "true_")
"""Column prefixes of the injected (known) values a consistency table may carry."""


def _column(rows: list[dict[str, Any]], names: Sequence[str]) -> F64:
    """The first of `names` the rows have, float64 (NaN where null or absent)."""
    for name in names:
        if rows and name in rows[0]:
            return np.array([np.nan if r.get(name) is None else float(r[name]) for r in rows],
                            dtype=np.float64)
    return np.full(len(rows), np.nan)


def consistency_data(table: Records, truth: Mapping[str, Mapping[str, float]] | None = None
                     ) -> dict[str, Any]:
    """The numbers behind the reprojection-consistency plot, one entry per table row.

    table: `stats/reprojection_consistency.parquet` rows; read by column name, so a table
    with more columns (or without the rotation ones) still plots: recording, camera,
    error_before and error_after are needed, offset_ms and roll_deg / pitch_deg / yaw_deg are
    NaN when absent. Injected values come from columns injected_<name> (or true_<name>) where
    the table has them, else from `truth`: recording -> {"offset_ms", "roll_deg",
    "pitch_deg", "yaw_deg"} (a synthetic recording's ground truth); NaN where unknown.
    Returns labels (N,) "recording/camera", before / after (N,) error, offset_ms (N,),
    rotation_deg (N, 3) roll, pitch, yaw, and injected_offset_ms (N,), injected_rotation_deg
    (N, 3). DataError when a needed column is missing.
    """
    rows = as_rows(table)
    need = ("recording", "camera", "error_before", "error_after")
    if rows and (missing := [c for c in need if c not in rows[0]]):
        raise DataError(f"reprojection consistency table lacks column(s) {missing}")
    names = [f"{a}_deg" for a in ROTATION_AXES]

    def injected(name: str) -> F64:
        col = _column(rows, [p + name for p in INJECTED_PREFIXES])
        known = [truth.get(r["recording"], {}).get(name) if truth else None for r in rows]
        fill = np.array([np.nan if k is None else float(k) for k in known], dtype=np.float64)
        out: F64 = np.where(np.isfinite(col), col, fill)
        return out

    return {"labels": [f"{r['recording']}/{r['camera']}" for r in rows],
            "before": _column(rows, ["error_before"]), "after": _column(rows, ["error_after"]),
            "offset_ms": _column(rows, ["offset_ms"]),
            "rotation_deg": np.stack([_column(rows, [n]) for n in names], axis=-1)
            if rows else np.zeros((0, 3)),
            "injected_offset_ms": injected("offset_ms"),
            "injected_rotation_deg": np.stack([injected(n) for n in names], axis=-1)
            if rows else np.zeros((0, 3))}
