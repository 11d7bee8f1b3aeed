"""Faults of a recording's geometry, injected into what the geometry check reads (a camera's
raw views and the recording's poses), so one clean recording serves every fault: the tests'
and `m3gd bench variants`' proof that the check sees them (`FAULTS`).

Each fault takes the camera sets by camera and the poses, and returns them changed as a
recording with that fault would have been read:

- `wrong_pose_frame`: a wheel joint's track read as the robot's (the body's track turned about
  its y axis at 8 rad/s, 0.3 m forward, 0.25 m left, 0.4 m down): issue 47's inspect fault;
- `cameras_swapped`: each camera's images read with the other's extrinsic (topics swapped);
- `rotation_2deg`, `rotation_5deg`: every camera's extrinsic turned about its optical y axis
  (yaw);
- `translation_10cm`: every camera's extrinsic moved 10 cm along its optical x axis;
- `clock_50ms`: every image read 50 ms late on the odometry clock (a camera clock offset);
- `time_reversed`: every sweep placed at the pose one sweep period (`SWEEP_PERIOD_S`) after its
  stamp: a stamp at the first firing read as one at the last.

Rendered faults (`RENDERED`) are better evidence: the generator records the rig's fault as a
real rig would (images from a camera turned 2 or 5 degrees or moved 10 cm from where
/tf_static says it is, or stamped 50 ms late by its clock) and the check reads the recording
as it is. `m3gd bench variants` renders those four; the other three stay injected
(`INJECTED`) because they are reading mistakes, not rig physics: a wrong pose frame and a
reversed time convention are decisions of the reader over a correct recording, and swapped
cameras are two topics read under each other's calibration (a recording cannot hold them
"swapped" without a reader that mixes them up). `FAULTS` keeps the injected form of all seven
(the check's unit tests' quick probes).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from packets.geometry_verdict import FAILED, INCONCLUSIVE, Verdict
from packets.reprojection_consistency import Track
from pipeline.analysis.geometry_views import CameraSet, Poses, judge_camera

Sets = dict[str, CameraSet]
Fault = Callable[[Sets, Poses], tuple[Sets, Poses]]

SWEEP_PERIOD_S = 0.1
"""A 10 Hz LiDAR's sweep period (s): how far a reversed time convention moves a sweep's stamp."""


def _moved(body: Poses, E: np.ndarray, cameras: list[str]) -> Poses:
    """`body` with each camera's T_base_cam right-multiplied by E (4, 4)."""
    T = dict(body.body.T_base)
    for cam in cameras:
        T[cam] = T[cam] @ E
    return Poses.of(dataclasses.replace(body.body, T_base=T))


def rotation(deg: float) -> Fault:
    """Every camera's extrinsic turned by `deg` about its optical y axis."""
    def fault(sets: Sets, body: Poses) -> tuple[Sets, Poses]:
        E = np.eye(4)
        E[:3, :3] = Rotation.from_euler("y", deg, degrees=True).as_matrix()
        return sets, _moved(body, E, list(sets))
    return fault


def translation(m: float) -> Fault:
    """Every camera's extrinsic moved `m` metres along its optical x axis."""
    def fault(sets: Sets, body: Poses) -> tuple[Sets, Poses]:
        E = np.eye(4)
        E[0, 3] = m
        return sets, _moved(body, E, list(sets))
    return fault


def clock(offset_s: float) -> Fault:
    """Every image read `offset_s` late on the odometry clock."""
    def fault(sets: Sets, body: Poses) -> tuple[Sets, Poses]:
        late = round(offset_s * 1e9)
        return {c: dataclasses.replace(cs, views=[dataclasses.replace(v, image_ns=v.image_ns + late)
                                                  for v in cs.views])
                for c, cs in sets.items()}, body
    return fault


def time_reversed(sets: Sets, body: Poses) -> tuple[Sets, Poses]:
    """Every sweep's pose read one sweep period after its stamp (a dropped view is kept)."""
    out = {}
    for c, cs in sets.items():
        views = []
        for v in cs.views:
            T, T0 = body.track.at(v.sweep_ns + SWEEP_PERIOD_S * 1e9), body.track.at(v.sweep_ns)
            if T is not None and T0 is not None:
                v = dataclasses.replace(v, T_odom_lidar=T @ np.linalg.solve(T0, v.T_odom_lidar))
            views.append(v)
        out[c] = dataclasses.replace(cs, views=views)
    return out, body


def wrong_pose_frame(sets: Sets, body: Poses) -> tuple[Sets, Poses]:
    """A wheel joint's track read as the robot's (module docstring); the views' LiDAR poses
    are read again from it."""
    base = body.body.base
    ang = 8.0 * (base.t - base.t[0]) * 1e-9
    spin = np.tile(np.eye(4), (len(ang), 1, 1))
    spin[:, :3, :3] = Rotation.from_euler("y", ang[:, None]).as_matrix()
    spin[:, :3, 3] = [0.3, 0.25, -0.4]
    wheel = Poses(Track(base.t, base.T @ spin), body.body)
    out = {}
    for c, cs in sets.items():
        views = []
        for v in cs.views:
            T, T0 = wheel.track.at(v.sweep_ns), body.track.at(v.sweep_ns)
            if T is not None and T0 is not None:  # T_odom_lidar = T0 @ T_base_lidar
                v = dataclasses.replace(v, T_odom_lidar=T @ np.linalg.solve(T0, v.T_odom_lidar))
            views.append(v)
        out[c] = dataclasses.replace(cs, views=views)
    return out, wheel


def cameras_swapped(sets: Sets, body: Poses) -> tuple[Sets, Poses]:
    """The first two cameras' extrinsics exchanged (unchanged with fewer than two cameras)."""
    if len(sets) < 2:
        return sets, body
    a, b = list(sets)[:2]
    T = dict(body.body.T_base)
    T[a], T[b] = T[b], T[a]
    return sets, Poses.of(dataclasses.replace(body.body, T_base=T))


FAULTS: dict[str, Fault] = {
    "wrong_pose_frame": wrong_pose_frame,
    "cameras_swapped": cameras_swapped,
    "rotation_2deg": rotation(2.0),
    "rotation_5deg": rotation(5.0),
    "translation_10cm": translation(0.10),
    "clock_50ms": clock(0.05),
    "time_reversed": time_reversed,
}
"""The faults of issue 47 by name."""


@dataclass(frozen=True)
class Rendered:
    """A fault as the generator renders it: `synth` keys (`SynthConfig`) and the camera
    displacement (`pipeline.synth.api.synthesize`'s `camera_offset_m`, (x, y, z) m along the
    optical axes) of the recording written with it."""

    synth: dict[str, object] = field(default_factory=dict)
    camera_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


RENDERED: dict[str, Rendered] = {
    "rotation_2deg": Rendered({"camera_extrinsic_error_deg": (0.0, 0.0, 2.0)}),  # yaw
    "rotation_5deg": Rendered({"camera_extrinsic_error_deg": (0.0, 0.0, 5.0)}),
    "translation_10cm": Rendered(camera_offset_m=(0.10, 0.0, 0.0)),
    "clock_50ms": Rendered({"camera_clock_offset_s": 0.05}),
}
"""The faults the generator renders into a recording (the same names as in `FAULTS`)."""
INJECTED: tuple[str, ...] = tuple(f for f in FAULTS if f not in RENDERED)
"""The faults only injected into what the check reads (module docstring: why)."""


def textureless(sets: Sets, body: Poses) -> tuple[Sets, Poses]:
    """Every image flat (one grey level): the views the check leaves out as it reads them
    (`geometry_views.FLAT_GRADIENT`), counted as flat."""
    return {c: dataclasses.replace(cs, views=[], flat=cs.flat + len(cs.views))
            for c, cs in sets.items()}, body


def judged(verdict: Verdict, faulty: bool) -> str:
    """How a camera's verdict stands: `ok` (right) or `false_fail` (wrong) on clean data;
    `detected` (failed, or inconclusive with a reason) or `missed` (ok) under a fault."""
    if not faulty:
        return "false_fail" if verdict.verdict == FAILED else "ok"
    seen = verdict.verdict == FAILED or (verdict.verdict == INCONCLUSIVE and bool(verdict.reason))
    return "detected" if seen else "missed"


def judge_all(sets: Sets, body: Poses,
              faults: bool | Collection[str] = True) -> dict[str, dict[str, Verdict]]:
    """Per case (`clean`, `textureless` and each fault of `FAULTS`: every one with `faults`
    True, those named when it is a collection), each camera's verdict."""
    cases: dict[str, Fault] = {"clean": lambda s, b: (s, b), "textureless": textureless}
    if faults:
        cases.update({f: FAULTS[f] for f in (FAULTS if faults is True else faults)})
    out = {}
    for name, fault in cases.items():
        cams, poses = fault(sets, body)
        out[name] = {c: judge_camera(cs, poses).verdict for c, cs in cams.items()}
    return out
