"""One candidate configuration judged by the run's geometry check, on the proof's views.

A `Rig` is what a written configuration would make of the recording: the pose source's keys
(an odometry topic, or a `/tf` edge with `odom_frame` and `base_frame`), the reference LiDAR
(topic, frame) and each camera's frame. `judge_rig` builds from it, for every camera, the
views the geometry check scores after packets (`pipeline.analysis.geometry_views`: the
sweep's edge points moved into the camera by T_odom_cam(image time)^-1 T_odom_lidar(sweep
time), both through the candidate's odometry and the static tree from its base frame) and
returns each camera's verdict (`judge_camera`: the shuffled-pairs null, the cause search).
A rig that cannot be built (fewer than two pose samples, a frame the static tree does not
reach from the base) raises `Unjudged` with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from packets.geometry_verdict import FAILED, OK
from packets.reprojection_consistency import CubicTrack, Track
from pipeline.analysis.align_lidar import BodyTrack
from pipeline.analysis.geometry_views import (
    FLAT_GRADIENT,
    MARGIN_S,
    CameraResult,
    CameraSet,
    Poses,
    RawView,
    azimuth_step,
    judge_camera,
    mean_gradient,
)
from pipeline.ingest.sources.tf_odometry import odom_edges
from pipeline.inspect.prove_read import ProofData
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]
LIDAR = "lidar"
"""The reference LiDAR's name among the sensors of a rig's `BodyTrack`."""


class Unjudged(Exception):
    """A candidate the proof cannot score; the message says why."""


@dataclass(frozen=True)
class Rig:
    """A candidate configuration: pose keys (`odometry` or `tf`, `odom_frame`, `base_frame`),
    the reference LiDAR's topic and frame, each camera's frame by image topic."""

    pose: dict[str, Any]
    lidar: str
    lidar_frame: str
    frames: dict[str, str]

    def key(self) -> str:
        """A hashable spelling of the rig (the proof judges each rig once)."""
        return repr((sorted(self.pose.items()), self.lidar, self.lidar_frame,
                     sorted(self.frames.items())))  # fmt: skip


def pose_series(data: ProofData, keys: dict[str, Any]) -> tuple[npt.NDArray[np.int64], F64]:
    """(stamps (N,) ns strictly increasing, T_odom_base (N, 4, 4)) of a pose candidate: its
    odometry topic's samples, or its /tf edge between `odom_frame` and `base_frame` (either
    direction, as ingest reads it)."""
    if "odometry" in keys:
        samples = list(data.odometry.get(str(keys["odometry"]), []))
    else:
        samples = [s for topic, msg in data.tf if topic == keys.get("tf")
                   for s in odom_edges(msg, str(keys["odom_frame"]), str(keys["base_frame"]))]
    samples.sort(key=lambda s: s[0])
    kept: list[tuple[int, F64]] = []
    for t, T in samples:
        if not kept or t > kept[-1][0]:
            kept.append((t, T))
    stamps = np.array([t for t, _ in kept], np.int64)
    return stamps, (np.stack([T for _, T in kept]) if kept else np.zeros((0, 4, 4)))


def _T_base(data: ProofData, base: str, frame: str, what: str) -> F64:
    """T_base_frame (4, 4) from the static tree; Unjudged naming the missing chain."""
    try:
        return np.asarray(data.static.lookup(base, frame), np.float64)
    except DataError as err:
        raise Unjudged(f"{what} frame {frame!r} not reached from {base!r} by static "
                       "transforms") from err  # fmt: skip


def rig_poses(data: ProofData, rig: Rig, cameras: list[str]) -> Poses:
    """The odometry and T_base_sensor of a rig (the LiDAR as `LIDAR`, cameras by image topic);
    Unjudged when it cannot be built."""
    stamps, T = pose_series(data, rig.pose)
    if stamps.size < 2:
        raise Unjudged(f"{stamps.size} pose sample(s) of it near the views")
    base = str(rig.pose.get("base_frame", ""))
    T_base = {LIDAR: _T_base(data, base, rig.lidar_frame, "LiDAR")}
    for cam in cameras:
        T_base[cam] = _T_base(data, base, rig.frames[cam], f"camera {cam}")
    return Poses(Track(stamps, T), BodyTrack(CubicTrack(stamps, T), T_base, data.path))


def camera_set(data: ProofData, rig: Rig, poses: Poses, cam: str) -> CameraSet:
    """One camera's raw views under a rig: each view's sweep of the rig's LiDAR with its pose
    at the sweep stamp, the image; a flat image counted and left out, a view whose image is
    not `MARGIN_S` inside the odometry left out."""
    views, tried, flat = [], 0, 0
    margin = round(MARGIN_S * 1e9)
    for sw, im in zip(data.sweeps.get(rig.lidar, []), data.images.get(cam, []), strict=False):
        if sw is None or im is None:
            continue
        tried += 1
        if mean_gradient(im.grey) < FLAT_GRADIENT:
            flat += 1
            continue
        T_lidar = poses.sensor_at(LIDAR, sw.stamp_ns)
        inside = all(poses.track.at(im.stamp_ns + d) is not None for d in (-margin, margin))
        if T_lidar is None or not inside or not len(sw.edges.points):
            continue
        views.append(RawView(sw.edges, T_lidar, im.stamp_ns, im.K, im.grey))
    return CameraSet(cam, views, tried, flat, lidar_step(data, rig.lidar))


def lidar_step(data: ProofData, lidar: str) -> float:
    """A LiDAR's azimuth step (rad) from its first sweep read, found once (0 without one)."""
    if lidar not in data.step_rad and lidar in data.first_xyz:
        data.step_rad[lidar] = azimuth_step(data.first_xyz[lidar])
    return data.step_rad.get(lidar, 0.0)


def judge_rig(data: ProofData, rig: Rig, cameras: list[str]) -> dict[str, CameraResult]:
    """Each camera's geometry verdict under `rig`; Unjudged when the rig cannot be built."""
    poses = rig_poses(data, rig, cameras)
    return {cam: judge_camera(camera_set(data, rig, poses, cam), poses) for cam in cameras}


@dataclass(frozen=True)
class CameraScore:
    """One camera under one candidate: verdict, LiDAR-edge score and z against the null
    (None without a null test), the verdict's reason."""

    camera: str
    verdict: str
    score: float | None
    z: float | None
    reason: str


@dataclass(frozen=True)
class Judged:
    """One candidate of a decision judged: `verdict` failed when a camera failed, ok when one
    is ok and none failed, else inconclusive; `score` and `z` the means over the cameras with
    a null test; `reason` why it is not ok (empty when ok)."""

    name: str
    verdict: str
    score: float | None
    z: float | None
    reason: str
    cameras: tuple[CameraScore, ...] = ()

    def short(self) -> str:
        """`name verdict (score s, z z)` or with the reason it was not scored."""
        if self.score is None:
            return f"{self.name} {self.verdict} ({self.reason})"
        return f"{self.name} {self.verdict} (score {self.score:.3f}, z {self.z:.1f})"


def judged(name: str, results: dict[str, CameraResult]) -> Judged:
    """A candidate's verdict from its cameras' (see `Judged`)."""
    cams = tuple(CameraScore(cam, r.verdict.verdict, r.test.observed if r.test else None,
                             _finite(r.test.z) if r.test else None,
                             r.verdict.reason + (f"; likely cause: {r.verdict.cause}"
                                                 if r.verdict.cause else ""))
                 for cam, r in results.items())  # fmt: skip
    verdicts = {c.verdict for c in cams}
    verdict = FAILED if FAILED in verdicts else OK if OK in verdicts else "inconclusive"
    scores = [c.score for c in cams if c.score is not None]
    zs = [c.z for c in cams if c.z is not None]
    why = "; ".join(f"{c.camera}: {c.reason}" for c in cams if c.verdict != OK)
    return Judged(name, verdict, float(np.mean(scores)) if scores else None,
                  float(np.mean(zs)) if zs else None,
                  "" if verdict == OK else (why or "no camera to score"), cams)  # fmt: skip


def _finite(x: float) -> float | None:
    """x, or None when infinite (a null without spread)."""
    return float(x) if np.isfinite(x) else None
