"""Recordings for the inspect tests: synthetic missions (cached per session) and a small
hand-written ROS1 bag of a rig the generator does not make (a camera named `cam0` with raw
bgr8 images and a camera_info that changes size, a Livox-like cloud with float64 absolute-ns
point time, an Ouster-like cloud with uint32 microseconds, a gap)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Writer

from pipeline.synth.api import synthesize
from schemas.config import SynthConfig
from tests.pipeline.ingest.bagkit import typestore

SMALL = {"image_width": 168, "image_height": 112, "points_per_sweep": 1024, "depth_maps": False}
T0 = 1_700_000_000_000_000_000
SWEEP_NS = 100_000_000


def synth(factory: pytest.TempPathFactory, name: str, **cfg: Any) -> Path:
    """Mission folder `name` (a synthetic corridor), made once per session."""
    root = factory.getbasetemp() / "inspect_recordings"
    mission = root / name
    if not (mission / "groundtruth" / "faults.json").exists():
        synthesize(root, SynthConfig(seed=2, scenes=["corridor"], **{**SMALL, **cfg}),
                   "corridor", name)  # fmt: skip
    return mission


def _cloud(ts: Any, stamp: int, frame: str, fields: list[tuple[str, int, int]], step: int,
           data: bytes, n: int) -> Any:  # fmt: skip
    m = ts.types
    pf = [m["sensor_msgs/msg/PointField"](name=k, offset=o, datatype=d, count=1)
          for k, o, d in fields]
    return m["sensor_msgs/msg/PointCloud2"](
        header=_header(ts, stamp, frame), height=1, width=n, fields=pf, is_bigendian=False,
        point_step=step, row_step=step * n, data=np.frombuffer(data, np.uint8), is_dense=True)


def _header(ts: Any, stamp: int, frame: str) -> Any:
    m = ts.types
    return m["std_msgs/msg/Header"](seq=0, stamp=m["builtin_interfaces/msg/Time"](
        sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=frame)


def livox_points(stamp: int, n: int = 200) -> bytes:
    """x, y, z, intensity float32, timestamp float64 absolute ns (livox_ros_driver2)."""
    dt = np.dtype({"names": ["x", "y", "z", "intensity", "timestamp"],
                   "formats": ["<f4", "<f4", "<f4", "<f4", "<f8"],
                   "offsets": [0, 4, 8, 12, 18], "itemsize": 26})
    a = np.zeros(n, dt)
    a["x"], a["y"], a["z"] = 5.0, np.linspace(-1, 1, n), 0.5
    a["timestamp"] = stamp + np.linspace(0, SWEEP_NS * 0.97, n)
    return a.tobytes()


def ouster_points(n: int = 200) -> bytes:
    """x, y, z float32, t uint32 microseconds from the header stamp."""
    dt = np.dtype({"names": ["x", "y", "z", "t"], "formats": ["<f4", "<f4", "<f4", "<u4"],
                   "offsets": [0, 4, 8, 12], "itemsize": 16})
    a = np.zeros(n, dt)
    a["x"], a["y"], a["z"] = 3.0, np.linspace(-1, 1, n), 0.2
    a["t"] = np.linspace(0, 97_000, n).astype(np.uint32)
    return a.tobytes()


def own_rig(folder: Path) -> Path:
    """A mission folder with one bag `rig.bag` of a rig the generator does not make."""
    folder.mkdir(parents=True, exist_ok=True)
    ts = typestore()
    m = ts.types
    path = folder / "rig.bag"
    with Writer(path) as w:
        conns = {}

        def put(topic: str, msgtype: str, stamp: int, msg: Any) -> None:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], stamp, ts.serialize_ros1(msg, msgtype))

        tfm = m["geometry_msgs/msg/TransformStamped"](
            header=_header(ts, T0, "base_link"), child_frame_id="livox_frame",
            transform=m["geometry_msgs/msg/Transform"](
                translation=m["geometry_msgs/msg/Vector3"](x=0.1, y=0.0, z=0.2),
                rotation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
        put("/tf_static", "tf2_msgs/msg/TFMessage", T0, m["tf2_msgs/msg/TFMessage"](
            transforms=[tfm]))
        for i in range(30):
            if 10 <= i < 15:
                continue  # a 0.6 s gap in every stream
            stamp = T0 + i * SWEEP_NS
            lv = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7),
                  ("timestamp", 18, 8)]
            put("/livox/lidar", "sensor_msgs/msg/PointCloud2", stamp,
                _cloud(ts, stamp, "livox_frame", lv, 26, livox_points(stamp), 200))
            put("/os/points", "sensor_msgs/msg/PointCloud2", stamp + 1,
                _cloud(ts, stamp, "os_sensor", [("x", 0, 7), ("y", 4, 7), ("z", 8, 7),
                                                 ("t", 12, 6)], 16, ouster_points(), 200))
            wd, ht = (64, 48) if i < 20 else (32, 24)  # the camera changes resolution
            put("/cam0/image_raw", "sensor_msgs/msg/Image", stamp + 2, m["sensor_msgs/msg/Image"](
                header=_header(ts, stamp, "cam0_optical"), height=ht, width=wd, encoding="bgr8",
                is_bigendian=0, step=wd * 3, data=np.zeros(wd * ht * 3, np.uint8)))
            put("/cam0/camera_info", "sensor_msgs/msg/CameraInfo", stamp + 3,
                m["sensor_msgs/msg/CameraInfo"](
                    header=_header(ts, stamp, "cam0_optical"), height=ht, width=wd,
                    distortion_model="plumb_bob", D=np.zeros(5),
                    K=np.array([wd, 0, wd / 2, 0, wd, ht / 2, 0, 0, 1], np.float64),
                    R=np.eye(3).ravel(), P=np.zeros(12), binning_x=0, binning_y=0,
                    roi=m["sensor_msgs/msg/RegionOfInterest"](
                        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)))
    return folder
