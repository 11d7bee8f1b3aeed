"""The LiDAR-to-image half of `m3gd align --consistency`: a camera's extrinsic rotation
recovered by aligning LiDAR edge points with image edges (`model.lidar_edges`).

Per `<recording>/<camera>` group: up to `max_views` accepted views (selection status ok, valid
in the cache), spread evenly over the recording and at least the largest swept clock offset
inside the camera's track; each view's selected sweep is decoded from the mission
(`pipeline.ingest.sweep_reader`), its edge points (depth and intensity steps between scan
neighbours) are moved into the camera at the recovered clock offset c: X_cam =
T_world_cam(stamp - c)^-1 T_world_cam(stamp) T_cam_lidar X_lidar (the recorded pose at the
image stamp is where select put the sweep; the track read c earlier is where the camera was),
and read against the cached image (grey levels). A view without edge points is left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.compute as pc

from model.lidar_edges import EdgeEstimate, EdgeView, align_rotation, camera_edges, scan_edges
from model.reprojection_consistency import Track
from pipeline.analysis.align import CacheGroup
from pipeline.ingest.sweep_reader import iter_sweeps
from schemas.cache_io import read_views
from schemas.recording_index import SELECTION, SELECTION_FILE, SWEEPS, read_index_table

METHOD = "lidar_edges"
"""The rotation method recorded in the table (Levinson & Thrun edge alignment)."""


@dataclass(frozen=True)
class EdgeViews:
    """A group's edge views (possibly none) and the views tried."""

    views: list[EdgeView]
    tried: int


def edge_views(group: CacheGroup, index_dir: Path, mission: Path, track: Track,
               offset_s: float, margin_s: float, max_views: int) -> EdgeViews:
    """The edge views of one group (module docstring); `index_dir` the recording's index
    folder, `mission` its recordings folder, `margin_s` the largest swept offset."""
    sel = read_index_table(index_dir / SELECTION_FILE, SELECTION)
    sel = sel.filter(pc.and_(pc.equal(sel["camera"], group.attrs.camera),
                             pc.equal(sel["status"], "ok")))
    n = group.attrs.n_views
    valid = read_views(group.path / "valid", list(range(n))).astype(bool)
    margin = round(margin_s * 1e9)
    rows = [r for r in sel.to_pylist() if 0 <= r["frame"] < n and valid[r["frame"]]
            and track.t[0] + margin <= r["stamp_ns"] <= track.t[-1] - margin]
    rows.sort(key=lambda r: int(r["stamp_ns"]))
    if len(rows) > max_views:
        keep = np.unique(np.linspace(0, len(rows) - 1, max_views).round().astype(int))
        rows = [rows[k] for k in keep]
    if not rows:
        return EdgeViews([], 0)
    sweeps = {r["sweep"]: r for r in read_index_table(index_dir / "sweeps.parquet",
                                                     SWEEPS).to_pylist()}
    order = sorted(range(len(rows)), key=lambda k: int(rows[k]["sweep"]))
    decoded = dict(zip(order, iter_sweeps(mission, [sweeps[rows[k]["sweep"]] for k in order]),
                       strict=True))
    images = read_views(group.path / "images", [int(r["frame"]) for r in rows])
    views = []
    for k, r in enumerate(rows):
        sw = decoded[k]
        T_cl = np.reshape(np.asarray(r["T_cam_lidar"], np.float64), (4, 4))
        T_wc = np.reshape(np.asarray(r["T_world_cam"], np.float64), (4, 4))
        T_true = track.at(r["stamp_ns"] - offset_s * 1e9)
        if T_true is None:
            continue
        T = np.linalg.solve(T_true, T_wc @ T_cl)
        edges = scan_edges(sw.xyz, sw.intensity)
        view = camera_edges(edges, T, np.reshape(np.asarray(r["K_out"], np.float64), (3, 3)),
                            images[k].astype(np.float64).mean(axis=-1))
        if len(view.points):
            views.append(view)
    return EdgeViews(views, len(rows))


def recover_rotation(ev: EdgeViews, max_rotation_deg: float,
                     steps: int = 9) -> EdgeEstimate | None:
    """The edge-alignment rotation of a group's views (None without any); `steps` grid
    points per axis and level."""
    if not ev.views:
        return None
    return align_rotation(ev.views, float(np.radians(max_rotation_deg)), steps=steps)
