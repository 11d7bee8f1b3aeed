"""`m3gd accuracy`: packet depth of an output directory against the recordings' ground truth.

For every accepted view of a recording with synthetic ground truth (`<mission>/groundtruth/`),
the ground-truth depth map of the image is remapped into the rectified output view (nearest
neighbour, the same map ingest uses for the pixels) and reduced to a reference depth per latent
cell (`packets.accuracy.cell_reference`). The packet's cell mean depth (1 / g[2] from the cache)
is compared with it. The robot's speed and yaw rate at the image come from the ground-truth
poses at its true capture time.

Outputs: `stats/accuracy/<rec>.parquet` (schema `schemas.tables.ACCURACY`,
queryable as table `accuracy` with `m3gd stats query`), `stats/accuracy_summary.json`, and the
plots `plots/accuracy_vs_dtau.png` and `plots/accuracy_map.png`.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import zarr

from packets.accuracy import (
    CellReference,
    abs_rel,
    cell_reference,
    depth_errors,
    dtau_bins,
    packet_depth,
    slope,
)
from packets.poses import interpolate_poses, rot_to_quat
from packets.support import PATCH_PX
from pipeline.ingest.calib.camera import RawCamera, build_rectifier, rectify_nearest
from pipeline.stages.common import index_path
from pipeline.synth.groundtruth import GT_DIR, read_poses
from schemas.atomic_io import write_text_atomic
from schemas.config import M3GDConfig
from schemas.errors import MissingInputError
from schemas.missions import mission_of, recording_names
from schemas.recording_index import CALIBRATION, SELECTION, read_index_table, table_path
from schemas.tables import ACCURACY, write_recording_part
from store.cache_io import read_views

F64 = npt.NDArray[np.float64]
ACCURACY_DIR = "accuracy"
SUMMARY_FILE = "accuracy_summary.json"
DTAU_EDGES_S: tuple[float, ...] = (0.0, 0.01, 0.02, 0.03, 0.05, 0.1, 0.2)
MOTION_DT_NS = 25_000_000
"""Half-width of the central difference for speed and yaw rate (25 ms)."""
TRAVEL_PER_FIGURE_M = 0.1
"""`absrel_per_100ms_dtau_at_1mps`: abs-rel change per 0.1 m of travel between image and sweep."""


@dataclass(frozen=True)
class ViewTruth:
    """One view of a recording with ground truth: its selection row and the reference."""

    camera: str
    frame: int
    stamp_ns: int
    dtau_s: float
    status: str
    sweep: int
    T_cam_lidar: F64
    K_out: F64
    ref: CellReference
    speed_mps: float
    yaw_rate_rps: float


@dataclass(frozen=True)
class _Truth:
    """Ground truth of one mission: image rows by (camera, header stamp), depth arrays, poses."""

    images: dict[tuple[str, int], dict[str, Any]]
    depth: dict[str, Any]
    stamps: npt.NDArray[np.int64]
    pos: F64
    quat: F64

    @classmethod
    def load(cls, mission: Path) -> _Truth:
        """Read a mission's ground truth (FileNotFoundError naming the folder if absent)."""
        gt = mission / GT_DIR
        if not (gt / "images.parquet").exists():
            raise MissingInputError(f"{gt}: no ground truth (accuracy needs synthetic recordings)")
        rows = pq.read_table(gt / "images.parquet").to_pylist()
        images = {(r["camera"], r["header_stamp_ns"]): r for r in rows if not r["duplicate"]}
        depth = {p.stem: zarr.open_array(str(p), mode="r") for p in (gt / "depth").glob("*.zarr")}
        stamps, T = read_poses(gt)
        quat = np.stack([rot_to_quat(t[:3, :3]) for t in T])
        return cls(images, depth, stamps, T[:, :3, 3].copy(), quat)

    def motion(self, capture_ns: int) -> tuple[float, float]:
        """Ground-plane speed (m/s) and yaw rate (rad/s) at a capture time (central difference)."""
        q = np.array([capture_ns - MOTION_DT_NS, capture_ns + MOTION_DT_NS], np.int64)
        s = interpolate_poses(self.stamps, self.pos, self.quat, q, 10**12)
        if not bool(s.ok.all()):
            return float("nan"), float("nan")
        dt = 2 * MOTION_DT_NS / 1e9
        speed = float(np.linalg.norm(s.T[1, :2, 3] - s.T[0, :2, 3]) / dt)
        yaw = np.arctan2(s.T[:, 1, 0], s.T[:, 0, 0])
        dyaw = (yaw[1] - yaw[0] + np.pi) % (2 * np.pi) - np.pi
        return speed, float(dyaw / dt)


def _rectifiers(idx: Path, out_hw: tuple[int, int], balance: float) -> dict[str, Any]:
    """The ingest rectifier of every camera of a recording, from its calibration table."""
    out = {}
    for c in read_index_table(table_path(idx, "calibration"), CALIBRATION).to_pylist():
        if c["kind"] != "camera":
            continue
        cam = RawCamera(c["sensor"], c["frame_id"], c["width"], c["height"], c["model"],
                        np.reshape(c["K"], (3, 3)), np.asarray(c["D"], np.float64))
        out[c["sensor"]] = build_rectifier(cam, out_hw, balance)
    return out


def view_truths(cfg: M3GDConfig, recording: str, selection: pa.Table | None = None,
                accepted_only: bool = True) -> Iterator[ViewTruth]:
    """Every (accepted) view of a recording with its ground-truth reference, in table order.

    selection: rows of schema SELECTION (default: the recording's selection.parquet).
    """
    idx = index_path(cfg, recording)
    truth = _Truth.load(mission_of(cfg, recording))
    sel = selection if selection is not None else read_index_table(
        table_path(idx, "selection"), SELECTION)
    hw = (cfg.ingest.out_height, cfg.ingest.out_width)
    rects = _rectifiers(idx, hw, cfg.ingest.rectify_balance)
    for r in sel.to_pylist():
        if accepted_only and r["status"] != "ok":
            continue
        gt_row = truth.images.get((r["camera"], r["stamp_ns"]))
        if gt_row is None or r["camera"] not in truth.depth or r["camera"] not in rects:
            continue
        raw = np.asarray(truth.depth[r["camera"]][gt_row["depth_index"]], np.float32)
        ref = cell_reference(rectify_nearest(raw, rects[r["camera"]]), PATCH_PX)
        speed, yaw_rate = truth.motion(int(gt_row["stamp_ns"]))
        yield ViewTruth(r["camera"], int(r["frame"]), int(r["stamp_ns"]), float(r["dtau_s"]),
                        r["status"], int(r["sweep"]), np.reshape(r["T_cam_lidar"], (4, 4)),
                        np.reshape(r["K_out"], (3, 3)), ref, speed, yaw_rate)


def cell_rows(recording: str, view: ViewTruth, depth: F64) -> dict[str, npt.NDArray[Any]]:
    """Columns of the accuracy table for the occupied cells (finite `depth` (H, W), m) of a view."""
    rr, cc = np.nonzero(np.isfinite(depth))
    gt = view.ref.median[rr, cc]
    n = rr.size
    return {
        "recording": np.full(n, recording, object), "camera": np.full(n, view.camera, object),
        "frame": np.full(n, view.frame, np.int64), "row": rr.astype(np.int16),
        "col": cc.astype(np.int16), "border": view.ref.border[rr, cc],
        "depth_m": depth[rr, cc], "gt_depth_m": gt, "gt_spread_m": view.ref.spread[rr, cc],
        "abs_rel": abs_rel(depth[rr, cc], gt), "dtau_s": np.full(n, view.dtau_s),
        "speed_mps": np.full(n, view.speed_mps), "yaw_rate_rps": np.full(n, view.yaw_rate_rps),
    }


def rows_table(parts: list[dict[str, npt.NDArray[Any]]]) -> pa.Table:
    """Concatenate `cell_rows` parts into a table of schema ACCURACY (NaN stored as null)."""
    if not parts:  # no view matched the ground truth: an empty table of the schema
        return ACCURACY.empty_table()
    cols = {}
    for f in ACCURACY:
        data = np.concatenate([p[f.name] for p in parts])
        if pa.types.is_floating(f.type):
            cols[f.name] = pa.array(data.astype(np.float64), f.type, mask=~np.isfinite(
                data.astype(np.float64)))
        else:
            cols[f.name] = pa.array(data.tolist() if data.dtype == object else data, f.type)
    return pa.table(cols, schema=ACCURACY)


def summarize(table: pa.Table) -> dict[str, Any]:
    """JSON summary of an accuracy table: overall, interior / border, per |Δτ| bin, slopes.

    `absrel_per_100ms_dtau_at_1mps`: least-squares slope of per-view mean abs-rel against the
    travel |Δτ| * speed between image and sweep, times 0.1 m (0.1 s at 1 m/s).
    """
    col = {n: table[n].to_numpy(zero_copy_only=False) for n in
           ("depth_m", "gt_depth_m", "border", "dtau_s", "speed_mps", "yaw_rate_rps", "abs_rel")}
    gt = np.asarray(col["gt_depth_m"], np.float64)
    d = np.asarray(col["depth_m"], np.float64)
    border = np.asarray(col["border"], bool)
    out: dict[str, Any] = {"cells": int(table.num_rows),
                           "cells_without_reference": int(np.sum(~np.isfinite(gt)))}
    out.update(depth_errors(d, gt).as_dict("depth_"))
    out["depth_absrel_interior"] = depth_errors(d[~border], gt[~border]).abs_rel
    out["depth_absrel_border"] = depth_errors(d[border], gt[border]).abs_rel
    out["border_cells"] = int(border.sum())
    adt = np.abs(np.asarray(col["dtau_s"], np.float64))
    bins = dtau_bins(adt, DTAU_EDGES_S)
    out["by_abs_dtau_ms"] = {
        f"{lo * 1e3:g}-{hi * 1e3:g}" if hi is not None else f">={lo * 1e3:g}":
            depth_errors(d[bins == i], gt[bins == i]).as_dict()
        for i, (lo, hi) in enumerate(zip(DTAU_EDGES_S, (*DTAU_EDGES_S[1:], None), strict=True))}
    out.update(_motion_summary(table, col))
    return out


def _view_means(table: pa.Table) -> pa.Table:
    """Per-view mean abs-rel with the view's |Δτ|, speed and yaw rate."""
    return table.group_by(["recording", "camera", "frame"]).aggregate(
        [("abs_rel", "mean"), ("dtau_s", "max"), ("speed_mps", "max"), ("yaw_rate_rps", "max")])


def _motion_summary(table: pa.Table, col: dict[str, Any]) -> dict[str, Any]:
    """Error by speed and |yaw rate| tercile and the abs-rel per 100 ms at 1 m/s slope."""
    views = _view_means(table)
    travel = np.abs(views["dtau_s_max"].to_numpy()) * views["speed_mps_max"].to_numpy()
    err = views["abs_rel_mean"].to_numpy(zero_copy_only=False).astype(np.float64)
    out: dict[str, Any] = {
        "views": int(views.num_rows),
        "absrel_per_100ms_dtau_at_1mps": slope(travel, err) * TRAVEL_PER_FIGURE_M,
        "max_speed_mps": float(np.nanmax(col["speed_mps"])) if table.num_rows else None,
        "max_abs_yaw_rate_rps": float(np.nanmax(np.abs(col["yaw_rate_rps"])))
        if table.num_rows else None,
    }
    d = np.asarray(col["depth_m"], np.float64)
    gt = np.asarray(col["gt_depth_m"], np.float64)
    for name, key in (("speed_mps", "by_speed_mps"), ("yaw_rate_rps", "by_abs_yaw_rate_rps")):
        x = np.abs(np.asarray(col[name], np.float64))
        if not x.size:
            continue
        edges = np.unique(np.nanquantile(x, [0.0, 1 / 3, 2 / 3]))
        b = dtau_bins(x, tuple(float(e) for e in edges))
        out[key] = {f">={lo:.3g}": depth_errors(d[b == i], gt[b == i]).as_dict()
                    for i, lo in enumerate(edges)}
    return out


def strict_json(data: Any) -> Any:
    """The same nested dicts / lists with NaN and +-Inf floats replaced by None (strict JSON)."""
    if isinstance(data, dict):
        return {k: strict_json(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [strict_json(v) for v in data]
    if isinstance(data, float) and not np.isfinite(data):
        return None
    return data


@dataclass(frozen=True)
class AccuracyReport:
    """What `run_accuracy` wrote: per-recording tables, the summary and the plots."""

    tables: list[Path]
    summary_path: Path
    summary: dict[str, Any]
    plots: list[Path]


def recording_accuracy(cfg: M3GDConfig, recording: str,
                       on_view: Callable[[int], None] | None = None) -> pa.Table:
    """The accuracy table of one recording, from its cached packets g; `on_view(1)` after
    each view (progress)."""
    g_path = cfg.layout.cache / recording
    parts = []
    for view in view_truths(cfg, recording):
        g = read_views(g_path / view.camera / "g", [view.frame])[0]
        parts.append(cell_rows(recording, view, packet_depth(g)))
        if on_view is not None:
            on_view(1)
    return rows_table(parts)


def run_accuracy(cfg: M3GDConfig, plots: bool = True,
                 on_view: Callable[[int], None] | None = None) -> AccuracyReport:
    """Accuracy of every recording with ground truth; writes tables, summary, plots.
    `on_view(1)` is called after each view compared (progress)."""
    base = cfg.layout.stats
    written, tables = [], []
    for rec in recording_names(cfg):
        if not (mission_of(cfg, rec) / GT_DIR).is_dir():
            continue
        t = recording_accuracy(cfg, rec, on_view)
        path = write_recording_part(t, ACCURACY, base / ACCURACY_DIR, rec)
        written.append(path)
        tables.append(t)
    if not tables:
        raise MissingInputError(f"{cfg.output_dir}: no recording with ground truth")
    table = pa.concat_tables(tables)
    summary = {"recordings": len(tables), "select_time_offset_s": cfg.select.time_offset_s,
               "front_surface": cfg.packets.front_surface,
               "front_margin_m": cfg.packets.front_margin_m,
               "front_margin_rel": cfg.packets.front_margin_rel, **summarize(table)}
    summary = strict_json(summary)
    summary_path = write_text_atomic(base / SUMMARY_FILE, json.dumps(summary, indent=1,
                                                                     allow_nan=False))
    figs = accuracy_plots(table, cfg.layout.plots) if plots else []
    return AccuracyReport(written, summary_path, summary, figs)


def accuracy_plots(table: pa.Table, out: Path) -> list[Path]:
    """Error vs |Δτ| (per view) and the error map of the view with the most occupied cells."""
    from pipeline.analysis import plots

    views = _view_means(table)
    paths = [plots.plot_error_vs_dtau(np.abs(views["dtau_s_max"].to_numpy()),
                                      views["abs_rel_mean"].to_numpy(zero_copy_only=False),
                                      out / "accuracy_vs_dtau.png")]
    counts = table.group_by(["recording", "camera", "frame"]).aggregate([("row", "count")])
    if counts.num_rows:
        k = counts.slice(int(np.argmax(counts["row_count"].to_numpy())), 1).to_pylist()[0]
        mask = pc.and_(pc.and_(pc.equal(table["recording"], k["recording"]),
                               pc.equal(table["camera"], k["camera"])),
                       pc.equal(table["frame"], k["frame"]))
        paths.append(plots.plot_error_map(table.filter(mask), out / "accuracy_map.png",
                                          f"{k['recording']} / {k['camera']} frame {k['frame']}"))
    return paths
