"""Odometry of the streaming pass: one pose message (or a /tf odom-base edge) as a T_odom_base
row, through the jump filter and its topic's checks, then indexed or rejected."""

from __future__ import annotations

from typing import Any

import numpy as np

from packets.poses import F64, compose, make_T, quat_to_rot, rot_to_quat
from pipeline.ingest.checks.check_fit import Release
from pipeline.ingest.checks.pose_checks import PoseVerdict, quat_norm_problem
from pipeline.ingest.checks.rejects import Reject
from pipeline.ingest.core.stream_state import POSE_CHECKS, StreamState, Writers
from pipeline.ingest.errors import BadPoseError
from pipeline.ingest.sources.bags import Message
from pipeline.ingest.sources.tf_odometry import pose_of
from schemas.recording_index import Reason

MAX_POSITION_M = 1e6
"""An odometry position farther than this (m) from its origin is corrupt (a robot's mission
spans kilometres); such poses are rejected, not interpolated into camera poses."""


def odometry_message(msg: Message, obj: Any, stamp: int, st: StreamState,
                     out: Writers) -> bool | None:  # fmt: skip
    """Index one pose message (`tf_odometry.POSE_TYPES`, by its declared type) as T_odom_base
    (re-based when its child frame is another than the base frame).

    BadPoseError for a non-finite, zero, absurdly far or (checks on) non-unit quaternion pose.
    """
    pose, child = pose_of(msg.msgtype, obj)
    p, q = pose.position, pose.orientation
    pos = np.array([p.x, p.y, p.z], dtype=np.float64)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    with np.errstate(over="ignore"):  # a flipped exponent: inf, refused as not unit below
        tiny = float(np.linalg.norm(quat)) < 1e-9
    if not (np.isfinite(pos).all() and np.isfinite(quat).all()) or tiny:
        raise BadPoseError(f"non-finite or zero pose: position {pos.tolist()}, "
                           f"quat {quat.tolist()}")
    if np.abs(pos).max() > MAX_POSITION_M:
        raise BadPoseError(f"position {pos.tolist()} m is beyond {MAX_POSITION_M:g} m of the "
                           "odometry origin: a corrupt pose")
    problem = quat_norm_problem(quat, st.checks.quat_norm_tol) if st.checks.enabled else None
    quat = quat / np.linalg.norm(quat)
    child = child or st.base_frame
    if child != st.base_frame:
        T = compose(make_T(quat_to_rot(quat), pos), st.tf.lookup(child, st.base_frame))
        pos, quat = T[:3, 3], rot_to_quat(T[:3, :3])
    return pose_row(msg, stamp, str(obj.header.frame_id).lstrip("/"), pos, quat, st, out,
                     problem)


def pose_row(msg: Message, stamp: int, frame: str, pos: F64, quat: F64, st: StreamState,
              out: Writers, quat_problem: str | None = None) -> bool | None:  # fmt: skip
    """Append one T_odom_base pose (position m, quaternion x, y, z, w) to the odometry table.

    With the checks on, the pose first passes the jump filter, then its topic's checks (the
    quaternion norm verdict `quat_problem` and the jump verdict): None (decided later, when its
    neighbours are read; `release_pose` keeps or rejects it and counts it).
    """
    row = {"stamp_ns": stamp, "frame_id": frame, "child_frame_id": st.base_frame,
           "position": pos.tolist(), "quat_xyzw": quat.tolist()}  # fmt: skip
    jumps = st.jump_filter()
    if jumps is None:
        out.odometry.append(row)
        return True
    for verdict in jumps.push(stamp, pos, (msg, row, quat_problem), judge=not st.trusted(msg)):
        pose_verdict(verdict, st, out)
    return None


def pose_verdict(verdict: PoseVerdict, st: StreamState, out: Writers) -> None:
    """Hand a pose judged by the jump filter to its topic's checks."""
    msg, row, quat_problem = verdict.item
    gate = st.fit(msg.topic, POSE_CHECKS)
    problems = {"quat_norm": quat_problem, "pose_jump": verdict.problem}
    for rel in gate.push((msg, row), problems, st.trusted(msg)):
        release_pose(rel, out)


def release_pose(rel: Release, out: Writers) -> None:
    """Keep (index and count) or reject a pose let go by its topic's checks."""
    msg, row = rel.item
    if rel.rejected_by is None:
        out.odometry.append(row)
        out.tally.kept[(msg.file, msg.topic)] += 1
        return
    out.rejects.add(Reject(msg.file, msg.topic, row["stamp_ns"], Reason.BAD_POSE,
                           rel.rejected_by[1]))  # fmt: skip
