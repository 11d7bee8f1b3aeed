"""The LiDAR-to-image half of `m3gd align --consistency`: a camera's extrinsic rotation
recovered by aligning LiDAR edge points with image edges (`model.lidar_edges`).

Per `<recording>/<camera>` group: up to `max_views` accepted views (selection status ok, valid
in the cache), spread evenly over the recording and at least the largest swept clock offset
inside the odometry; each view's selected sweep is decoded from the mission
(`pipeline.ingest.sources.sweep_reader`), its edge points (depth and intensity steps between scan
neighbours) are moved into the camera at the recovered clock offset c:
X_cam = (B(tau - c) T_base_cam)^-1 B(sweep stamp) T_base_lidar X_lidar, with tau the image
time on the odometry clock that select used (the sweep's stamp less the row's delta tau: the
image stamp less the `select.time_offset_s` the selection was made with) and B the recorded
odometry T_odom_base read by cubic splines (`model.reprojection_consistency.CubicTrack`:
slerp between 20 Hz samples of a turning robot errs by tenths of a pixel, which the alignment
would read as a rotation), and read against the cached image (grey levels). A view without
edge points is left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow.compute as pc

from packets.edges import EdgeView, camera_edges, scan_edges
from packets.reprojection_consistency import CubicTrack
from packets.rigid import quat_pose_T
from pipeline.analysis.align import CacheGroup
from pipeline.analysis.edge_align import EdgeEstimate, align_rotation
from pipeline.ingest.sources.sweep_reader import iter_sweeps
from pipeline.select.views import load_odometry
from schemas.errors import DataError
from schemas.recording_index import (
    CALIBRATION,
    SELECTION,
    SELECTION_FILE,
    SWEEPS,
    read_index_table,
    table_path,
)
from store.cache_io import read_views

F64 = npt.NDArray[np.float64]

METHOD = "lidar_edges"
"""The rotation method recorded in the table (Levinson & Thrun edge alignment)."""


@dataclass(frozen=True)
class BodyTrack:
    """The recorded odometry T_odom_base as a cubic track (stamps on the odometry clock) and
    each sensor's T_base_sensor (4, 4) by name."""

    base: CubicTrack
    T_base: dict[str, F64]
    calibration: Path

    def sensor_at(self, sensor: str, stamp_ns: float) -> F64 | None:
        """T_odom_sensor (4, 4) at a stamp (ns, odometry clock); None outside the odometry."""
        T = self.base.at(stamp_ns)
        if sensor not in self.T_base:
            raise DataError(f"{self.calibration}: no row of sensor {sensor!r}; ingest again")
        return None if T is None else T @ self.T_base[sensor]


def body_track(index_dir: Path) -> BodyTrack:
    """The odometry and calibration of a recording's index folder as a `BodyTrack`; a
    DataError naming the table when it holds fewer than 2 odometry samples."""
    odo = load_odometry(index_dir)
    if odo.stamps.size < 2:
        raise DataError(f"{table_path(index_dir, 'odometry')}: {odo.stamps.size} odometry "
                        "sample(s); the edge alignment reads poses between two or more")
    T = quat_pose_T(odo.quat, odo.pos)  # scipy's rounding: why, see quat_pose_T
    path = table_path(index_dir, "calibration")
    calib = read_index_table(path, CALIBRATION).to_pylist()
    return BodyTrack(CubicTrack(odo.stamps, T),
                     {str(r["sensor"]): np.reshape(np.asarray(r["T_base_sensor"], np.float64),
                                                   (4, 4)) for r in calib}, path)


@dataclass(frozen=True)
class EdgeViews:
    """A group's edge views (possibly none) and the views tried."""

    views: list[EdgeView]
    tried: int


def image_time_ns(row: dict[str, Any]) -> int:
    """A selection row's image time on the odometry clock (ns): its sweep's stamp less its
    delta tau (select's tau, whatever `select.time_offset_s` it was made with)."""
    return int(row["sweep_stamp_ns"]) - round(float(row["dtau_s"]) * 1e9)


def edge_views(group: CacheGroup, index_dir: Path, mission: Path, offset_s: float,
               margin_s: float, max_views: int) -> EdgeViews:
    """The edge views of one group (module docstring); `index_dir` the recording's index
    folder, `mission` its recordings folder, `margin_s` the largest swept offset."""
    body = body_track(index_dir)
    track = body.base
    sel = read_index_table(index_dir / SELECTION_FILE, SELECTION)
    sel = sel.filter(pc.and_(pc.equal(sel["camera"], group.attrs.camera),
                             pc.equal(sel["status"], "ok")))
    n = group.attrs.n_views
    valid = read_views(group.path / "valid", list(range(n))).astype(bool)
    margin = round(margin_s * 1e9)
    rows = [r for r in sel.to_pylist() if 0 <= r["frame"] < n and valid[r["frame"]]
            and track.t[0] + margin <= image_time_ns(r) <= track.t[-1] - margin]
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
        T_cam = body.sensor_at(group.attrs.camera, image_time_ns(r) - offset_s * 1e9)
        T_lidar = body.sensor_at(str(sweeps[r["sweep"]]["lidar"]), r["sweep_stamp_ns"])
        if T_cam is None or T_lidar is None:
            continue
        T = np.asarray(np.linalg.solve(T_cam, T_lidar), np.float64)
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
