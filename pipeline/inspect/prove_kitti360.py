"""What inspect's proof reads from a KITTI-360 root, as `prove_read` reads bags, and the rig
a layout without alternatives fixes (`fixed_decisions`).

Views are spread over the Velodyne's timestamps.txt stamps (`prove_read.view_times`); per view
the first sweep at or after it (`.bin`, every point at its sweep's stamp: the release has no
per-point time), each camera's first `data_rect` PNG at or after the sweep's stamp plus
`LAG_NS` less `IMAGE_LEAD_NS` (already rectified: P_rect's K, resampled to at most `WIDTH_PX`
wide). Poses: poses.txt (T_world_pose at image_00's frame stamps) within `WINDOW_NS` of a
view, as the odometry topic `poses`. The static tree is the one ingest builds
(`kitti360_layout.read_kitti360_static`): `pose` -> each camera folder (its rectified frame)
and `pose` -> `velodyne` through camera 0 (calib_cam_to_velo.txt).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any, TypeVar

import numpy as np

from packets.poses import invert_T
from pipeline.ingest.calib.camera import RawCamera, Rectifier
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.sources.kitti360_calib import (
    parse_cam_to_pose,
    parse_perspective,
    parse_poses,
    parse_rigid_file,
    parse_stamp,
)
from pipeline.ingest.sources.kitti360_layout import VELODYNE, Kitti360Layout, rect_to_base
from pipeline.ingest.sources.kitti360_read import sweep_points
from pipeline.ingest.sources.pointcloud import Sweep
from pipeline.inspect.model import Candidate, Decision, Inspection
from pipeline.inspect.prove_read import (
    IMAGE_LEAD_NS,
    LAG_NS,
    WINDOW_NS,
    ImageView,
    ProofData,
    SweepView,
    image_view,
    small_rectifier,
    sweep_view,
    view_times,
)
from schemas.errors import DataError

T = TypeVar("T")
POSES = "poses"
"""The pose source's name: poses.txt as an odometry topic."""
POSE_FRAME, WORLD_FRAME, VELO_FRAME = "pose", "world", "velodyne"
FIXED = "the layout's only one"


def fixed_decisions(ins: Inspection) -> tuple[Decision, ...]:
    """The rig of an inspection that decided nothing because its layout leaves no choice (one
    odometry, one LiDAR, each camera its own frame): one candidate per decision, so the proof
    judges the layout's geometry; () when the inspection has not exactly one odometry and a
    LiDAR."""
    if len(ins.odometry) != 1 or not ins.clouds:
        return ()
    topic, odom, base = ins.odometry[0]
    cloud = ins.clouds[0]
    out = [_one("pose", topic, {"odometry": topic, "odom_frame": odom, "base_frame": base}),
           _one("lidar", cloud.topic, {"topic": cloud.topic, "frame": cloud.frame_id})]
    out += [_one(f"camera {c.image_topic}", c.frame_id, {"frame": c.frame_id})
            for c in ins.cameras if c.frame_id]  # fmt: skip
    return tuple(out)


def _one(what: str, name: str, keys: dict[str, Any]) -> Decision:
    """A decision with its one candidate."""
    return Decision(what, name, (Candidate(name, keys, (FIXED,), 1.0),), False, FIXED)


def _stamps(layout: Kitti360Layout, name: str) -> np.ndarray:
    """A sensor's stamps (int64 ns) by frame; -1 where a line is unusable."""
    path = layout.sensor_dir(name) / "timestamps.txt"
    out = []
    for i, line in enumerate(layout.text(path, f"{name} stamps").splitlines()):
        if line.strip():
            try:
                out.append(parse_stamp(line, f"{layout.rel(path)} line {i + 1}"))
            except DataError:
                out.append(-1)
    return np.array(out, np.int64)


def _frame_at(stamps: np.ndarray, at_ns: int) -> int | None:
    """The first frame whose stamp is at or after `at_ns` (unusable stamps skipped)."""
    later = np.flatnonzero(stamps >= at_ns)
    return int(later[np.argmin(stamps[later])]) if later.size else None


def _static(layout: Kitti360Layout, problems: list[str]) -> tuple[TfTree, dict[str, Any]]:
    """The static tree (module docstring) and the perspective cameras (none, with the
    problem said, when perspective.txt cannot be read)."""
    try:
        persp = parse_perspective(layout.calib("perspective.txt"),
                                  "calibration/perspective.txt")  # fmt: skip
    except DataError as err:
        persp = {}
        problems.append(str(err))
    to_pose = parse_cam_to_pose(layout.calib("calib_cam_to_pose.txt"),
                                "calibration/calib_cam_to_pose.txt")  # fmt: skip
    T_velo_cam0 = parse_rigid_file(layout.calib("calib_cam_to_velo.txt"),
                                   "calibration/calib_cam_to_velo.txt")  # fmt: skip
    tree = TfTree()
    if "image_00" in to_pose:
        tree.add(POSE_FRAME, VELO_FRAME, to_pose["image_00"] @ invert_T(T_velo_cam0))
    for name, cam in persp.items():
        if name in to_pose:
            tree.add(POSE_FRAME, name, rect_to_base(to_pose[name], cam.R_rect))
    return tree, persp


def _sweep(layout: Kitti360Layout, stamps: np.ndarray, at_ns: int,
           data: ProofData) -> SweepView | None:  # fmt: skip
    """The first Velodyne sweep at or after `at_ns`, its edges."""
    frame = _frame_at(stamps, at_ns)
    if frame is None:
        return None
    path = layout.frame_file(VELODYNE, frame)
    try:
        c, xyz, refl = sweep_points(path.read_bytes(), layout.rel(path))
    except FileNotFoundError as err:
        raise DataError(f"{layout.rel(path)}: no such file") from err
    stamp = int(stamps[frame])
    sw = Sweep(xyz, refl.astype(np.float32), np.full(c.valid, stamp, np.int64), c)
    return sweep_view(VELODYNE, stamp, stamp, sw, data)


def _image(layout: Kitti360Layout, name: str, rect: Rectifier, stamps: np.ndarray,
           at_ns: int) -> ImageView | None:  # fmt: skip
    """The camera's first PNG at or after `at_ns`, resampled, grey."""
    frame = _frame_at(stamps, at_ns)
    if frame is None:
        return None
    path = layout.frame_file(name, frame)
    try:
        msg = SimpleNamespace(data=np.frombuffer(path.read_bytes(), np.uint8))
    except FileNotFoundError as err:
        raise DataError(f"{layout.rel(path)}: no such file") from err
    rgb = rect.remap(rect.decode_message("png", msg, layout.rel(path)))
    return image_view(int(stamps[frame]), rgb, rect)


def _poses(layout: Kitti360Layout, times: list[int]) -> list[tuple[int, Any]]:
    """(stamp ns, T_world_pose (4, 4)) of poses.txt rows within WINDOW_NS of `times`."""
    frames, Ts = parse_poses(layout.text(layout.poses, "poses"), layout.rel(layout.poses))
    stamps = _stamps(layout, "image_00")
    out = []
    for f, T_ in zip(frames.tolist(), Ts, strict=True):
        s = int(stamps[f]) if 0 <= f < stamps.size else -1
        if s >= 0 and any(abs(s - t) <= WINDOW_NS for t in times):
            out.append((s, T_))
    return out


def kitti360_proof_data(path: Path, ins: Inspection, lidars: list[str]) -> ProofData:
    """The proof's views of a KITTI-360 root (module docstring); what cannot be read is one
    line of `ProofData.problems`."""
    layout = Kitti360Layout.open(path)
    problems: list[str] = []
    tree, persp = _static(layout, problems)
    data = ProofData(path, tree, problems=problems)
    velo = _stamps(layout, VELODYNE)
    good = velo[velo >= 0]
    times = view_times(int(good.min()), int(good.max())) if good.size else []
    if not times:
        data.problems.append("the Velodyne's recording is too short for views")
        return data
    data.sweeps[VELODYNE] = [_guard(data, _sweep, layout, velo, t, data) for t in times]
    for cam in ins.cameras:
        name = cam.image_topic
        if name not in persp:
            data.problems.append(f"camera {name}: calibration/perspective.txt has no P_rect")
            continue
        p = persp[name]
        rect = small_rectifier(RawCamera(name, name, p.width, p.height, "pinhole", p.K,
                                         np.zeros(5)))  # fmt: skip
        stamps = _stamps(layout, name)
        data.images[name] = [None if s is None else _guard(
            data, _image, layout, name, rect, stamps, s.stamp_ns + LAG_NS - IMAGE_LEAD_NS)
            for s in data.sweeps[VELODYNE]]  # fmt: skip
    data.odometry[POSES] = _poses(layout, times)
    return data


def _guard(data: ProofData, read: Callable[..., T], *args: Any) -> T | None:
    """`read(*args)`, or None with the problem noted (a damaged frame leaves its view out)."""
    try:
        return read(*args)
    except (DataError, ValueError, OSError) as err:
        data.problems.append(str(err))
        return None
