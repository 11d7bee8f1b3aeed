"""`m3gd inspect` of a KITTI-360 root: its sensor folders as topics, calibration and poses.

Topics: `image_00`, `image_01` (data_rect PNGs), `velodyne_points` (.bin sweeps) with the
stamps of their timestamps.txt (rates, gaps), and `poses` (poses.txt rows at image_00 frames).
TF: the static edges the calibration gives (`pose` -> image_0N, `pose` -> `velodyne`); the
layout has no dynamic TF. The Velodyne has no per-point time: every point is at its sweep's
timestamps.txt stamp (the convention is stated, not inferred).
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from pipeline.ingest.sources.kitti360_calib import (
    VELO_DTYPE,
    PerspectiveCamera,
    parse_cam_to_pose,
    parse_perspective,
    parse_poses,
    parse_timestamps,
)
from pipeline.ingest.sources.kitti360_layout import (
    CAMERA_FOLDERS,
    VELODYNE,
    Kitti360Layout,
)
from pipeline.inspect.cameras import magic
from pipeline.inspect.model import (
    Calibration,
    CameraReport,
    CloudReport,
    Convention,
    Inspection,
    PointField,
    SweepTime,
    TfEdge,
    TopicStats,
)
from pipeline.inspect.rates import timing
from pipeline.inspect.tf import shape
from schemas.errors import DataError

SAMPLED = 3
POSE_FRAME, WORLD_FRAME, VELO_FRAME = "pose", "world", "velodyne"
NO_POINT_TIME = Convention("kitti360: no per-point time", None, None,
                           "every point takes its sweep's timestamps.txt stamp")  # fmt: skip


def _stamps(layout: Kitti360Layout, name: str, notes: list[str]) -> np.ndarray:
    """A sensor's stamps (int64 ns), empty (with a note) when its timestamps.txt is unusable."""
    path = layout.sensor_dir(name) / "timestamps.txt"
    try:
        return parse_timestamps(layout.text(path, f"{name} stamps"), layout.rel(path))
    except DataError as err:
        notes.append(str(err))
        return np.zeros(0, np.int64)


def _topic(layout: Kitti360Layout, name: str, kind: str, stamps: np.ndarray) -> TopicStats:
    """One sensor folder as a topic."""
    t = timing(stamps)
    return TopicStats(name, f"kitti360 {kind}", int(stamps.size), t.first_ns, t.last_ns,
                      t.rate_hz, t.period_s, t.n_gaps, t.gaps,
                      (layout.rel(layout.sensor_dir(name)),))  # fmt: skip


def _camera(layout: Kitti360Layout, name: str, cam: PerspectiveCamera | None,
            stamps: np.ndarray) -> CameraReport:  # fmt: skip
    """A camera folder: the sizes of its first PNGs, P_rect from perspective.txt."""
    sizes, kinds = [], []
    for frame in range(min(SAMPLED, int(stamps.size))):
        path = layout.frame_file(name, frame)
        if not path.is_file():
            continue
        data = path.read_bytes()
        kinds.append(magic(data[:8]))
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is not None and (int(img.shape[1]), int(img.shape[0])) not in sizes:
            sizes.append((int(img.shape[1]), int(img.shape[0])))
    cals = () if cam is None else (Calibration(
        int(stamps[0]) if stamps.size else 0, "pinhole (rectified)", 0, cam.width, cam.height,
        float(cam.K[0, 0]), float(cam.K[1, 1]), float(cam.K[0, 2]), float(cam.K[1, 2])),)
    return CameraReport(name, "kitti360 data_rect", "calibration/perspective.txt"
                        if cam is not None else None, name,
                        f"{', '.join(dict.fromkeys(kinds)) or 'no'} files in data_rect/",
                        tuple(sizes), cals, False,
                        None if cam is not None else f"perspective.txt has no P_rect for {name}")



def _cloud(layout: Kitti360Layout, stamps: np.ndarray) -> CloudReport:
    """The Velodyne folder: float32 x, y, z, reflectance; point counts of its first sweeps."""
    fields = tuple(PointField(n, 7, "<f4", 4 * i, 1) for i, n in enumerate(VELO_DTYPE.names or ()))
    sweeps, error = [], None
    for frame in range(min(SAMPLED, int(stamps.size))):
        path = layout.frame_file(VELODYNE, frame)
        n = path.stat().st_size // VELO_DTYPE.itemsize if path.is_file() else 0
        if not path.is_file():
            error = f"{layout.rel(path)}: missing"
        s = int(stamps[frame])
        sweeps.append(SweepTime(s, s, int(n), None, None, 0, s, s, 0))
    period = float(np.median(np.diff(stamps))) / 1e9 if stamps.size > 1 else None
    return CloudReport(VELODYNE, VELO_FRAME, fields, VELO_DTYPE.itemsize, 0, 0, 1, False, False,
                       None, None, tuple(sweeps), period, (), NO_POINT_TIME, error)  # fmt: skip


def _calibration(layout: Kitti360Layout, notes: list[str]
                 ) -> tuple[dict[str, PerspectiveCamera], list[TfEdge]]:  # fmt: skip
    """Perspective cameras and the static edges of the calibration files (notes on failures)."""
    cams: dict[str, PerspectiveCamera] = {}
    edges: list[TfEdge] = []
    try:
        cams = parse_perspective(layout.calib("perspective.txt"), "calibration/perspective.txt")
    except DataError as err:
        notes.append(str(err))
    try:
        to_pose = parse_cam_to_pose(layout.calib("calib_cam_to_pose.txt"),
                                    "calibration/calib_cam_to_pose.txt")  # fmt: skip
        edges = [TfEdge(POSE_FRAME, n, True, "calibration/calib_cam_to_pose.txt", 1)
                 for n in sorted(to_pose)]  # fmt: skip
        if (layout.root / "calibration" / "calib_cam_to_velo.txt").is_file():
            edges.append(TfEdge("image_00", VELO_FRAME, True,
                                "calibration/calib_cam_to_velo.txt", 1))  # fmt: skip
    except DataError as err:
        notes.append(str(err))
    return cams, edges


def inspect_kitti360(path: Path, began: float) -> Inspection:
    """The inspection of a KITTI-360 root (one sequence)."""
    layout = Kitti360Layout.open(path)
    notes: list[str] = [f"sequence {layout.seq}; {NO_POINT_TIME.note}"]
    cams, edges = _calibration(layout, notes)
    topics, cameras = [], []
    for name in CAMERA_FOLDERS:
        if layout.sensor_dir(name).is_dir():
            stamps = _stamps(layout, name, notes)
            topics.append(_topic(layout, name, "camera", stamps))
            cameras.append(_camera(layout, name, cams.get(name), stamps))
    velo = _stamps(layout, VELODYNE, notes)
    topics.append(_topic(layout, VELODYNE, "lidar", velo))
    odometry: list[tuple[str, str, str]] = []
    try:
        frames, _ = parse_poses(layout.text(layout.poses, "poses"), layout.rel(layout.poses))
        topics.append(TopicStats("poses", "kitti360 poses (T_world_pose at image_00 frames)",
                                 int(frames.size), files=(layout.rel(layout.poses),)))
        odometry.append(("poses", WORLD_FRAME, POSE_FRAME))
    except DataError as err:
        notes.append(str(err))
    files = {layout.rel(p): p.stat().st_size for p in sorted(path.rglob("*.txt"))}
    return Inspection(str(path), f"kitti360 (sequence {layout.seq})", files, tuple(topics),
                      shape(edges, {}), (_cloud(layout, velo),), tuple(cameras),
                      tuple(odometry), tuple(notes), time.perf_counter() - began)  # fmt: skip
