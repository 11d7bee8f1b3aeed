"""Rig variants of the TF tree and pose sources, and the decisions inspect must reach on each.

Each function changes a written ROS1 mission of the default sensors (the generator's /tf
carries `base -> odom`, GrandTour's direction; the odometry topic `odom -> base`):

- `pose_on_tf`: the odometry topic dropped, the pose only on /tf, beside moving joint frames
  (wheels, as `robot_state_publisher` puts them in the same TFMessage), the body renamed (so
  that the pose edge sorts before or after the wheels), the pose edge in either direction,
  `map -> odom` with jumps (localization) above it, or a second moving edge from another root
  (a motion-capture marker no sensor hangs off);
- `odometry_disagrees`: the odometry topic's positions scaled (another estimator) while /tf
  keeps the generator's;
- `image_frame_differs`: one camera's images stamped with a frame_id the TF tree lacks
  (its CameraInfo and the tree keep the calibrated frame);
- `lidar_half_rate`: a second LiDAR (`variants_rig.add_lidar`) at half the first one's rate:
  the first stays the reference, both are declared.

`TF_VARIANTS` (name -> `TfVariant`) declares each; `Truth` is what inspect must decide on a
mission (pose source keys, whether that is ambiguous, the LiDARs reference first, each
camera's frame), `default_truth` the default recording's and `TfVariant.truth` a variant's.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from rosbags.rosbag1 import Reader

from packets.poses import invert_T, make_T, quat_to_rot
from pipeline.synth.rosio import Msgs
from pipeline.synth.variants_rig import ODOMETRY_T, add_lidar, rewrite_bag, ros1_typestore

F64 = npt.NDArray[np.float64]
TF_T = "tf2_msgs/msg/TFMessage"
WHEELS = ("wheel_left_link", "wheel_right_link")
JUMP_EVERY_NS = 500_000_000
"""`map -> odom` jumps every 0.5 s."""
JUMP_M = 0.4
"""... by 0.4 m along x (a localization correction)."""
HALF_RATE_LIDAR = ("/second/points", "second_lidar")
"""(topic, frame) of `lidar_half_rate`'s second LiDAR."""


@dataclass(frozen=True)
class Truth:
    """What inspect must decide on a mission: the pose source's configuration keys (`odometry`
    topic or `tf` topic, `odom_frame`, `base_frame`), whether the evidence leaves it
    ambiguous, the LiDAR topics (the reference first) and each camera's frame (by image
    topic)."""

    pose: dict[str, str]
    pose_ambiguous: bool
    lidars: tuple[str, ...]
    camera_frames: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class TfVariant:
    """A TF or pose-source variant: its description and `pose_on_tf` / other arguments."""

    description: str
    kind: str = "pose_on_tf"
    body: str = "base"
    wheels_first: bool = True
    odom_child: bool = False
    map_jumps: bool = False
    second_root: bool = False

    def truth(self, default: Truth) -> Truth:
        """The decisions inspect must reach on this variant of a mission whose default
        decisions are `default`."""
        if self.kind == "odometry_disagrees":
            return replace(default, pose_ambiguous=True)
        if self.kind == "image_frame_differs":
            return default  # the calibrated frame, which the TF tree holds
        if self.kind == "lidar_half_rate":
            return replace(default, lidars=(*default.lidars, HALF_RATE_LIDAR[0]))
        return replace(default, pose={"tf": "/tf", "odom_frame": "odom", "base_frame": self.body})


TF_VARIANTS: dict[str, TfVariant] = {
    "tf_wheels": TfVariant("pose only on /tf: odom -> base beside base -> wheel_left_link and "
                           "wheel_right_link in one message (the wheels first, by name too)"),
    "tf_wheels_body_last": TfVariant("pose only on /tf, the body named `trunk`: odom -> trunk "
                                     "sorts before the wheels; the pose first in each message",
                                     body="trunk", wheels_first=False),
    "tf_odom_child": TfVariant("pose only on /tf as base -> odom (GrandTour's direction), "
                               "beside wheels", odom_child=True),
    "tf_map_jumps": TfVariant("pose only on /tf: map -> odom (jumping 0.4 m every 0.5 s) and "
                              "odom -> base, beside wheels", map_jumps=True),
    "tf_two_roots": TfVariant("pose only on /tf: odom -> base and a second moving edge from "
                              "another root (mocap -> base_marker, no sensor below)",
                              second_root=True),
    "odometry_disagrees": TfVariant("an odometry topic whose positions are 1.25 x those of the "
                                    "/tf edge (another estimator)", kind="odometry_disagrees"),
    "image_frame_differs": TfVariant("one camera's images carry a frame_id the TF tree lacks "
                                     "(its camera_info and TF keep the calibrated frame)",
                                     kind="image_frame_differs"),
    "lidar_half_rate": TfVariant("a second LiDAR at half the first one's rate (every other "
                                 "sweep, mounted 0.2 m to the side)", kind="lidar_half_rate"),
}  # fmt: skip
"""The TF and pose-source variants by name (a part of `variants_rig.RIG_VARIANTS`)."""


def _wheel_T(stamp_ns: int, side: float) -> F64:
    """T_body_wheel (4, 4): a wheel 0.3 m to the side turning about its axle at 2 rad/s."""
    a = 2.0 * stamp_ns / 1e9
    c, s = np.cos(a), np.sin(a)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return make_T(R, [0.0, 0.3 * side, -0.1])


def _jump_T(stamp_ns: int, t0_ns: int) -> F64:
    """T_map_odom (4, 4): a step of JUMP_M along x every JUMP_EVERY_NS."""
    return make_T(np.eye(3), [JUMP_M * ((stamp_ns - t0_ns) // JUMP_EVERY_NS), 0.0, 0.0])


def tf_edges(v: TfVariant, stamp_ns: int, t0_ns: int, T_odom_base: F64
             ) -> list[tuple[str, str, F64]]:  # fmt: skip
    """The (parent, child, T_parent_child) edges of one /tf message of variant `v`."""
    pose = ((v.body, "odom", invert_T(T_odom_base)) if v.odom_child
            else ("odom", v.body, T_odom_base))  # fmt: skip
    wheels = [(v.body, w, _wheel_T(stamp_ns, side)) for w, side in zip(WHEELS, (1.0, -1.0),
                                                                        strict=True)]
    edges = [*wheels, pose] if v.wheels_first else [pose, *wheels]
    if v.map_jumps:
        edges.append(("map", "odom", _jump_T(stamp_ns, t0_ns)))
    if v.second_root:
        edges.append(("mocap", "base_marker", make_T(np.eye(3), [2.0, 1.0, 0.0]) @ T_odom_base))
    return edges


def pose_on_tf(mission: Path, v: TfVariant) -> int:
    """Rewrite the mission as variant `v` (kind `pose_on_tf`): every bag of the odometry topic
    removed, every /tf message replaced by `tf_edges`, `base` renamed `v.body` on /tf_static.
    Returns the /tf messages written."""
    ts = ros1_typestore()
    msgs = Msgs(ts)
    done = 0
    t0: list[int] = []

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        nonlocal done
        if msgtype != TF_T:
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        if topic.endswith("tf_static"):
            for e in msg.transforms:
                e.header.frame_id = v.body if e.header.frame_id == "base" else e.header.frame_id
            return topic, msgtype, ts.serialize_ros1(msg, msgtype)
        (e,) = msg.transforms
        head = int(e.header.stamp.sec) * 10**9 + int(e.header.stamp.nanosec)
        t0.append(t0[0] if t0 else head)
        T_odom_base = invert_T(_T_of(e.transform))
        out = msgs.tf([msgs.transform(head, p, c, T) for p, c, T in
                       tf_edges(v, head, t0[0], T_odom_base)])  # fmt: skip
        done += 1
        return topic, msgtype, ts.serialize_ros1(out, msgtype)

    for bag in sorted(mission.glob("*.bag")):
        with Reader(bag) as reader:
            kinds = {c.msgtype for c in reader.connections}
        if kinds == {ODOMETRY_T}:
            bag.unlink()
        elif TF_T in kinds:
            rewrite_bag(bag, convert)
    return done


def _T_of(tf: Any) -> F64:
    """(4, 4) T of a geometry_msgs/Transform (translation, rotation x, y, z, w)."""
    t, q = tf.translation, tf.rotation
    return make_T(quat_to_rot([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])


def odometry_disagrees(mission: Path, scale: float = 1.25) -> int:
    """Every odometry position multiplied by `scale` (orientation, header and /tf unchanged).
    Returns the messages rewritten."""
    ts = ros1_typestore()
    done = 0

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        nonlocal done
        if msgtype != ODOMETRY_T:
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        p = msg.pose.pose.position
        p.x, p.y, p.z = p.x * scale, p.y * scale, p.z * scale
        done += 1
        return topic, msgtype, ts.serialize_ros1(msg, msgtype)

    for bag in sorted(mission.glob("*.bag")):
        rewrite_bag(bag, convert)
    return done


def image_frame_differs(mission: Path, image_topic: str, suffix: str = "_optical_frame") -> str:
    """The images of `image_topic` stamped with frame_id `<frame><suffix>` (a frame the TF tree
    lacks); its CameraInfo keeps the calibrated frame. Returns the images' new frame_id."""
    ts = ros1_typestore()
    new: list[str] = []

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        if topic != image_topic:
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        msg.header.frame_id = f"{msg.header.frame_id}{suffix}"
        new[:] = [msg.header.frame_id]
        return topic, msgtype, ts.serialize_ros1(msg, msgtype)

    for bag in sorted(mission.glob("*.bag")):
        with Reader(bag) as reader:
            if any(c.topic == image_topic for c in reader.connections):
                rewrite_bag(bag, convert)
    return new[0] if new else ""


def apply_tf_variant(mission: Path, name: str, image_topic: str,
                     lidar: tuple[str, str] = ("/boxi/hesai/points_undistorted", "hesai_lidar")
                     ) -> None:  # fmt: skip
    """Apply TF variant `name` to a written mission (`image_topic`: the camera whose images
    `image_frame_differs` restamps; `lidar`: the (topic, frame) `lidar_half_rate` copies)."""
    v = TF_VARIANTS[name]
    if v.kind == "lidar_half_rate":
        add_lidar(mission, lidar, HALF_RATE_LIDAR, make_T(np.eye(3), [0.0, 0.2, 0.0]), every=2)
    elif v.kind == "odometry_disagrees":
        odometry_disagrees(mission)
    elif v.kind == "image_frame_differs":
        image_frame_differs(mission, image_topic)
    else:
        pose_on_tf(mission, v)
