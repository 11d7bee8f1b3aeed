"""Where odometry comes from: a pose topic, by its declared message type, or `/tf`.

Pose topics (`POSE_TYPES`): `nav_msgs/Odometry` (the pose of `child_frame_id` in
`header.frame_id`), `geometry_msgs/PoseWithCovarianceStamped` and `geometry_msgs/PoseStamped`
(no child frame: the pose is that of `ingest.topics.base_frame` in `header.frame_id`). The type
is the one the bag declares for the topic (its connection record), never guessed from values.

Without an odometry topic in any bag, the odom-base edge of `/tf`, in either direction:
GrandTour publishes `odom` as a *child* of `base` on /tf (T_base_odom); a tree built the ROS
way would have it the other way round. Either direction is accepted and turned into T_odom_base.
"""

from __future__ import annotations

from typing import Any

from packets.poses import F64, invert_T
from pipeline.ingest.calib.tf_tree import transform_to_T
from pipeline.ingest.sources.bags import stamp_ns
from schemas.errors import DataError


def odom_edges(msg: Any, odom_frame: str, base_frame: str) -> list[tuple[int, F64]]:
    """(stamp ns, T_odom_base (4, 4)) for every odom-base transform in a tf2_msgs/TFMessage."""
    out = []
    for ts in msg.transforms:
        parent, child = ts.header.frame_id.lstrip("/"), ts.child_frame_id.lstrip("/")
        if (parent, child) == (odom_frame, base_frame):
            out.append((stamp_ns(ts), transform_to_T(ts.transform)))
        elif (parent, child) == (base_frame, odom_frame):
            out.append((stamp_ns(ts), invert_T(transform_to_T(ts.transform))))
    return out


ODOMETRY_T = "nav_msgs/msg/Odometry"
POSE_COV_T = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE_T = "geometry_msgs/msg/PoseStamped"
POSE_TYPES = (ODOMETRY_T, POSE_COV_T, POSE_T)
"""Message types an odometry topic may have."""


def pose_of(msgtype: str, msg: Any) -> tuple[Any, str]:
    """(geometry_msgs/Pose, child frame: '' when the type has none) of a pose message of
    declared type `msgtype` (one of POSE_TYPES; ValueError otherwise)."""
    if msgtype == ODOMETRY_T:
        return msg.pose.pose, str(msg.child_frame_id).lstrip("/")
    if msgtype == POSE_COV_T:
        return msg.pose.pose, ""
    if msgtype == POSE_T:
        return msg.pose, ""
    raise ValueError(f"odometry of type {msgtype} is not read ({', '.join(POSE_TYPES)})")


def check_odometry_type(topic: str, msgtype: str, where: str) -> None:
    """DataError naming `where`, the topic, its type and the config key when the odometry
    topic is not of a type in POSE_TYPES."""
    if msgtype not in POSE_TYPES:
        raise DataError(f"{where}: the odometry topic {topic} (ingest.topics.odometry) is "
                        f"{msgtype or 'of no declared type'}; odometry is read from "
                        f"{', '.join(POSE_TYPES)}, or from the /tf odom-base edge when no bag "
                        "holds the odometry topic")
