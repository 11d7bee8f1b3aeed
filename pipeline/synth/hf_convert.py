"""The same synthetic recording in GrandTour's Hugging Face layout, made from its finished bags.

Every message of the configured topics becomes one row, in bag reading order, with the values
the bag holds (JPEG bytes, float32 points, float64 poses) and the release's conventions:
float64-second stamps, points padded to the longest sweep and sliced by `valid`, x, y, z, w
quaternion arrays, camera_info and transforms as group attributes, `tf` entries mapping parent
coordinates into the child frame (the inverse of the ROS edge). What the release does not keep
is dropped here too: per-point time, the `/tf` odometry edge, log times.
Faults injected into the bags (corrupt JPEG, duplicate or swapped stamps, gaps, NaN points, an
empty sweep, missing CameraInfo or TF edge) carry over as the same rows; a truncated bag is
converted before it is cut (as the ROS2 copy).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from packets.poses import invert_T, make_T, quat_to_rot
from pipeline.synth.hf_layout import Columns, HfWriter, RowTable, stamp_seconds, tf_entry
from pipeline.synth.lidar import HESAI_DTYPE
from schemas.config import HfConfig, TopicsConfig
from schemas.errors import DataError

CAMERA_DESCRIPTION = "HDR camera, 10 Hz, JPEG in images/<topic>/NNNNNN.jpeg (row of timestamp)"


def _messages(bag: Path, topics: set[str]) -> Iterator[tuple[str, Any]]:
    """(topic, deserialized message) of `topics` in one bag, in log-time order."""
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        if not conns:  # rosbags reads every connection when given none
            return
        for conn, _, raw in reader.messages(connections=conns):
            yield conn.topic, reader.deserialize(raw, conn.msgtype)


def _stamp_ns(msg: Any) -> int:
    """Header stamp (int64 ns)."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _head(msg: Any) -> dict[str, Any]:
    """The timestamp and sequence_id of a row."""
    return {"timestamp": stamp_seconds(_stamp_ns(msg)), "sequence_id": int(msg.header.seq)}


def bags_to_hf(bags: list[Path], dst: Path, topics: TopicsConfig, cameras: list[str],
               hf: HfConfig | None = None, zarr_format: int = 2) -> dict[str, int]:  # fmt: skip
    """Write the HF layout of a mission's bags into `dst`; rows per group."""
    hf = hf or HfConfig()
    w = HfWriter(dst, zarr_format)
    static = _static_edges(bags, topics.tf_static)
    w.set_attrs(hf.tf_group, description="static transforms", frame_id=topics.base_frame,
                topic=topics.tf_static, tf=static)  # fmt: skip
    for cam in cameras:
        _camera(w, bags, topics, cam, hf.group(cam), static)
    _lidar(w, bags, topics, hf.lidar_group, static)
    _odometry(w, bags, topics, hf.odometry_group)
    w.close()
    return {name: t.count for name, t in w.tables.items()}


def _static_edges(bags: list[Path], topic: str) -> dict[str, Any]:
    """The `tf` attribute: per child frame, T_child_parent (inverse of the /tf_static edge)."""
    out: dict[str, Any] = {}
    for bag in bags:
        for _, msg in _messages(bag, {topic}):
            for ts in msg.transforms:
                t, q = ts.transform.translation, ts.transform.rotation
                T = make_T(quat_to_rot([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])
                out[ts.child_frame_id.lstrip("/")] = tf_entry(ts.header.frame_id.lstrip("/"),
                                                              invert_T(T))  # fmt: skip
    return out


def _camera(w: HfWriter, bags: list[Path], topics: TopicsConfig, cam: str, group: str,
            static: dict[str, Any]) -> None:  # fmt: skip
    """Rows and JPEG files of one camera; camera_info from its first CameraInfo."""
    image_t, info_t = topics.image_topic(cam), topics.info_topic(cam)
    frame = topics.frame_of(cam)
    table = w.topic(group, image_t, frame, CAMERA_DESCRIPTION, {})
    info: dict[str, Any] | None = None
    for bag in bags:
        for topic, msg in _messages(bag, {image_t, info_t}):
            if topic == info_t:
                info = info or {"K": np.asarray(msg.K).tolist(), "D": np.asarray(msg.D).tolist(),
                                "distortion_model": str(msg.distortion_model),
                                "width": int(msg.width), "height": int(msg.height)}  # fmt: skip
                continue
            row = table.append(**_head(msg))
            w.image(group, row, np.asarray(msg.data, dtype=np.uint8).tobytes())
    attrs: dict[str, Any] = {"transform": _transform(static, frame)}
    if info is not None:
        attrs["camera_info"] = info
    w.set_attrs(group, **attrs)


def _transform(static: dict[str, Any], frame: str) -> dict[str, Any] | None:
    """A sensor group's `transform` attribute: its `tf` entry with the child frame named."""
    entry = static.get(frame)
    if entry is None:
        return None
    return {**entry, "child_frame_id": frame}


def _lidar(w: HfWriter, bags: list[Path], topics: TopicsConfig, group: str,
           static: dict[str, Any]) -> None:  # fmt: skip
    """Sweeps padded to the longest one (zeros), `valid` points each; no per-point time."""
    sizes = [int(m.width) * int(m.height) for b in bags for _, m in _messages(b, {topics.lidar})]
    max_p = max([*sizes, 1])
    cols = {"points": ((max_p, 3), "float32"), "valid": ((1,), "int32"),
            "intensity": ((max_p,), "float32"), "ring": ((max_p,), "uint16")}  # fmt: skip
    table = w.topic(group, topics.lidar, topics.lidar_frame, "Hesai XT32 undistorted points",
                    cols, transform=_transform(static, topics.lidar_frame))  # fmt: skip
    for bag in bags:
        for _, msg in _messages(bag, {topics.lidar}):
            _sweep_row(table, msg, max_p)


def _sweep_row(table: RowTable, msg: Any, max_p: int) -> None:
    """One padded sweep row from a Hesai-layout PointCloud2."""
    if int(msg.point_step) != HESAI_DTYPE.itemsize:
        raise DataError(f"point_step {msg.point_step} is not the Hesai layout's 26")
    n = int(msg.width) * int(msg.height)
    pts = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes()[: n * 26], dtype=HESAI_DTYPE)
    xyz = np.zeros((max_p, 3), np.float32)
    xyz[:n] = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
    inten, ring = np.zeros(max_p, np.float32), np.zeros(max_p, np.uint16)
    inten[:n], ring[:n] = pts["intensity"], pts["ring"]
    table.append(**_head(msg), points=xyz, valid=[n], intensity=inten, ring=ring)


def _odometry(w: HfWriter, bags: list[Path], topics: TopicsConfig, group: str) -> None:
    """Odometry rows: pose_pos (3), pose_orien (x, y, z, w), covariances, twist."""
    cols: Columns = {"pose_pos": ((3,), "float64"), "pose_orien": ((4,), "float64"),
                     "pose_cov": ((36,), "float64"), "twist_lin": ((3,), "float64"),
                     "twist_ang": ((3,), "float64"), "twist_cov": ((36,), "float64")}  # fmt: skip
    table = w.topic(group, topics.odometry, topics.odom_frame, "state estimator odometry", cols)
    for bag in bags:
        for _, msg in _messages(bag, {topics.odometry}):
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            v, a = msg.twist.twist.linear, msg.twist.twist.angular
            table.append(**_head(msg), pose_pos=[p.x, p.y, p.z], pose_orien=[q.x, q.y, q.z, q.w],
                         pose_cov=msg.pose.covariance, twist_lin=[v.x, v.y, v.z],
                         twist_ang=[a.x, a.y, a.z], twist_cov=msg.twist.covariance)  # fmt: skip
