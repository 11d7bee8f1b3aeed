"""Per-view and per-cell statistics rows of one shard (Arrow tables, schemas in schemas.tables).

Per-shard files are written by the packets stage next to nothing else; the stats
stage merges them per recording (concatenation: every row is final, so the merge
is exact).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from packets.statistics import cell_depth_stats
from packets.support import SupportSets
from schemas.layout import OutputLayout
from schemas.tables import CELL_STATS, VIEW_STATS, write_table

PARTS_DIR = "parts"


@dataclass
class ShardStats:
    """Accumulates view and cell rows of one recording-camera shard."""

    recording: str
    camera: str
    views: list[dict[str, object]] = field(default_factory=list)
    cells: list[dict[str, np.ndarray]] = field(default_factory=list)

    def add_view(self, frame: int, stamp_ns: int, sweep_stamp_ns: int | None,
                 dtau_s: float | None, sup: SupportSets | None, reject: str | None) -> None:
        """Record one view: its support sets (None when rejected before packets)."""
        row: dict[str, object] = {
            "recording": self.recording, "camera": self.camera, "frame": frame,
            "stamp_ns": stamp_ns, "sweep_stamp_ns": sweep_stamp_ns, "dtau_s": dtau_s,
            "supported_cells": None, "points_in_frustum": None, "points_too_near": None,
            "depth_mean_m": None, "depth_min_m": None, "depth_max_m": None,
            "reject_reason": reject,
        }
        if sup is not None:
            self._add_support(row, frame, sup)
        self.views.append(row)

    def _add_support(self, row: dict[str, object], frame: int, sup: SupportSets) -> None:
        """Fill depth and support figures of a view and its occupied cells."""
        stats = cell_depth_stats(sup.cell, sup.depth, sup.n_cells)
        occ = np.flatnonzero(stats.n)
        has = sup.depth.size > 0
        row.update(
            supported_cells=int(occ.size), points_in_frustum=int(sup.depth.size),
            points_too_near=sup.n_too_near,
            depth_mean_m=float(sup.depth.mean()) if has else None,
            depth_min_m=float(sup.depth.min()) if has else None,
            depth_max_m=float(sup.depth.max()) if has else None,
        )
        width = sup.grid_hw[1]
        self.cells.append({
            "frame": np.full(occ.size, frame, np.int64),
            "row": (occ // width).astype(np.int16), "col": (occ % width).astype(np.int16),
            "n": stats.n[occ], "depth_mean_m": stats.mean[occ], "depth_var_m2": stats.var[occ],
        })

    def view_table(self) -> pa.Table:
        """Per-view rows as a table of schema VIEW_STATS."""
        return pa.Table.from_pylist(self.views, schema=VIEW_STATS)

    def cell_table(self) -> pa.Table:
        """Per-cell rows (occupied cells only) as a table of schema CELL_STATS."""
        cols = {k: np.concatenate([c[k] for c in self.cells]) if self.cells else np.zeros(0)
                for k in ("frame", "row", "col", "n", "depth_mean_m", "depth_var_m2")}
        n = len(cols["frame"])
        data = {"recording": [self.recording] * n, "camera": [self.camera] * n, **cols}
        return pa.table({f.name: pa.array(data[f.name], f.type) for f in CELL_STATS},
                        schema=CELL_STATS)

    def write(self, output_dir: Path, shard: int) -> None:
        """Write this shard's part files (atomic; a rerun overwrites them)."""
        base = OutputLayout(output_dir).stats / PARTS_DIR / self.recording
        stem = f"{self.camera}-{shard:06d}"
        write_table(self.view_table(), VIEW_STATS, base / f"view_stats-{stem}.parquet")
        write_table(self.cell_table(), CELL_STATS, base / f"cell_stats-{stem}.parquet")
