"""Odometry of the streaming pass: one pose message (or a /tf odom-base edge) as a T_odom_base
row with its quaternion norm verdict; its topic's gated pass (`gated_pass.GatedPass`) runs the
jump filter and the checks, then indexes or rejects it."""

from __future__ import annotations

from typing import Any

import numpy as np

from packets.poses import F64, compose, make_T, quat_to_rot, rot_to_quat
from pipeline.ingest.checks.pose_checks import quat_norm_problem
from pipeline.ingest.core.gated_pass import Indexed
from pipeline.ingest.core.stream_state import StreamState
from pipeline.ingest.errors import BadPoseError
from pipeline.ingest.sources.bags import Message
from pipeline.ingest.sources.tf_odometry import pose_of

MAX_POSITION_M = 1e6
"""An odometry position farther than this (m) from its origin is corrupt (a robot's mission
spans kilometres); such poses are rejected, not interpolated into camera poses."""


def odometry_message(msg: Message, obj: Any, stamp: int, st: StreamState) -> Indexed:
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
    return pose_row(msg, stamp, str(obj.header.frame_id).lstrip("/"), pos, quat, st, problem)


def pose_row(msg: Message, stamp: int, frame: str, pos: F64, quat: F64, st: StreamState,
             quat_problem: str | None = None) -> Indexed:  # fmt: skip
    """One T_odom_base pose (position m, quaternion x, y, z, w) as an odometry index row, with
    the quaternion norm verdict `quat_problem`; its topic's gated pass runs the jump filter and
    the checks (none for a message a verified checksum vouches for)."""
    row = {"stamp_ns": stamp, "frame_id": frame, "child_frame_id": st.base_frame,
           "position": pos.tolist(), "quat_xyzw": quat.tolist()}  # fmt: skip
    return Indexed(row, msg.file, {"quat_norm": quat_problem}, trusted=st.trusted(msg))
