"""Odometry from `/tf` when no odometry topic exists: the odom-base edge, in either direction.

GrandTour publishes `odom` as a *child* of `base` on /tf (T_base_odom); a tree built the ROS
way would have it the other way round. Either direction is accepted and turned into T_odom_base.
"""

from __future__ import annotations

from typing import Any

from packets.poses import F64, invert_T
from pipeline.ingest.bags import stamp_ns
from pipeline.ingest.tf_tree import transform_to_T


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
