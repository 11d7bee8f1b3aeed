"""ROS1 bag output with rosbags (Noetic typestore + tf2_msgs/TFMessage), LZ4 chunks; message
builders for the GrandTour topics; optional conversion of the bags to ROS2 MCAP.

Bag time is the header stamp (as in GrandTour) unless a fault asks otherwise.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import lz4.frame
import numpy as np
import numpy.typing as npt
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from packets.poses import rot_to_quat
from pipeline.synth.lidar import HESAI_FIELDS
from pipeline.synth.rig import FisheyeCamera
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]
CHUNK_BYTES = 1 << 20
IMAGE_T = "sensor_msgs/msg/CompressedImage"
INFO_T = "sensor_msgs/msg/CameraInfo"
CLOUD_T = "sensor_msgs/msg/PointCloud2"
ODOM_T = "nav_msgs/msg/Odometry"
TF_T = "tf2_msgs/msg/TFMessage"


Compression = Literal["roslz4", "lz4", "none"]
"""Chunk compression of a written bag: LZ4 as `rosbag record` writes it (with the stream
checksum), LZ4 as rosbags' writer does (no checksum), or uncompressed chunks."""


def roslz4(data: bytes) -> bytes:
    """One chunk as roslz4 (`rosbag record --lz4`) compresses it: an LZ4 frame of independent
    blocks with the XXH32 content checksum, which roslz4 requires when it reads a chunk
    (blocks of lz4's default 64 kB: a cut chunk still yields its whole blocks).

    rosbags' writer leaves the checksum out, so a flipped byte of such a chunk decompresses to
    other bytes without an error; with it, lz4.frame refuses the chunk (a damaged region).
    """
    return bytes(lz4.frame.compress(data, 0, block_linked=False, content_checksum=True))


def set_chunk_compression(writer: Writer, compression: Compression = "roslz4") -> None:
    """Make an unopened rosbags ROS1 `writer` write chunks with `compression`."""
    if compression not in ("roslz4", "lz4", "none"):
        raise DataError(f"unknown chunk compression {compression!r}: roslz4, lz4 or none")
    if compression == "none":
        return
    writer.set_compression(Writer.CompressionFormat.LZ4)
    if compression == "roslz4":
        writer.compressor = roslz4


def ros1_typestore() -> Any:
    """ROS1 Noetic types plus tf2_msgs/msg/TFMessage (absent from that store)."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(
        get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
    )
    return ts


class Msgs:
    """Builders of the ROS1 messages of a GrandTour recording."""

    def __init__(self, ts: Any) -> None:
        """Bind the typestore's classes."""
        self.ts = ts
        self._t = ts.types

    def header(self, stamp_ns: int, frame: str, seq: int = 0) -> Any:
        """std_msgs/Header at an int64 ns stamp."""
        time = self._t["builtin_interfaces/msg/Time"](
            sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9
        )
        return self._t["std_msgs/msg/Header"](seq=seq, stamp=time, frame_id=frame)

    def image(self, stamp_ns: int, frame: str, jpeg: npt.NDArray[np.uint8], seq: int) -> Any:
        """sensor_msgs/CompressedImage, format 'jpg'."""
        return self._t[IMAGE_T](header=self.header(stamp_ns, frame, seq), format="jpg", data=jpeg)

    def camera_info(self, stamp_ns: int, cam: FisheyeCamera, seq: int) -> Any:
        """sensor_msgs/CameraInfo (ROS1 D/K/R/P), the camera's model, P = [K | 0]."""
        P = np.zeros((3, 4))
        P[:, :3] = cam.K
        roi = self._t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return self._t[INFO_T](
            header=self.header(stamp_ns, cam.frame_id, seq), height=cam.height, width=cam.width,
            distortion_model=cam.model, D=cam.D.astype(np.float64), K=cam.K.ravel().copy(),
            R=np.eye(3).ravel(), P=P.ravel(), binning_x=0, binning_y=0, roi=roi,
        )  # fmt: skip

    def cloud(self, stamp_ns: int, frame: str, points: npt.NDArray[np.void], seq: int,
              layout: list[tuple[str, int, int]] = HESAI_FIELDS, dense: bool = False) -> Any:
        """sensor_msgs/PointCloud2 of packed points with the fields `layout` (name, offset,
        datatype; default the Hesai driver's, point_step 26) and the is_dense flag `dense`."""
        PF = self._t["sensor_msgs/msg/PointField"]
        fields = [PF(name=n, offset=o, datatype=dt, count=1) for n, o, dt in layout]
        n = int(points.size)
        step = points.dtype.itemsize
        return self._t[CLOUD_T](
            header=self.header(stamp_ns, frame, seq), height=1, width=n, fields=fields,
            is_bigendian=False, point_step=step, row_step=step * n,
            data=np.frombuffer(points.tobytes(), np.uint8), is_dense=dense,
        )  # fmt: skip

    def transform(self, stamp_ns: int, parent: str, child: str, T: F64) -> Any:
        """geometry_msgs/TransformStamped carrying T_parent_child."""
        V3, Q = self._t["geometry_msgs/msg/Vector3"], self._t["geometry_msgs/msg/Quaternion"]
        q = rot_to_quat(T[:3, :3])
        tr = self._t["geometry_msgs/msg/Transform"](
            translation=V3(x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            rotation=Q(x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        return self._t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp_ns, parent), child_frame_id=child, transform=tr
        )

    def tf(self, transforms: list[Any]) -> Any:
        """tf2_msgs/TFMessage."""
        return self._t[TF_T](transforms=transforms)

    def odometry(self, stamp_ns: int, frame: str, child: str, T: F64, v: F64, w: F64,
                 seq: int) -> Any:  # fmt: skip
        """nav_msgs/Odometry: pose T_frame_child, body twist (v m/s, w rad/s), zero covariance."""
        t = self._t
        q = rot_to_quat(T[:3, :3])
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        V3 = t["geometry_msgs/msg/Vector3"]
        twist = t["geometry_msgs/msg/Twist"](linear=V3(x=v[0], y=v[1], z=v[2]),
                                             angular=V3(x=w[0], y=w[1], z=w[2]))  # fmt: skip
        return t[ODOM_T](
            header=self.header(stamp_ns, frame, seq), child_frame_id=child,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )  # fmt: skip


class Bag:
    """One ROS1 bag being written (LZ4 chunks as `rosbag record` writes them, with their
    checksum); connections made on first use per topic."""

    def __init__(self, path: Path, ts: Any) -> None:
        """Open `path` for writing (it must not exist)."""
        self.path = path
        self._ts = ts
        self._w = Writer(path)
        set_chunk_compression(self._w)
        self._w.chunk_threshold = CHUNK_BYTES
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self._w.open()

    def write(self, topic: str, msgtype: str, bag_time_ns: int, msg: Any) -> None:
        """Serialize and append one message at bag time `bag_time_ns`."""
        if topic not in self._conns:
            latch = 1 if topic.endswith("tf_static") else None
            self._conns[topic] = self._w.add_connection(topic, msgtype, typestore=self._ts,
                                                        latching=latch)  # fmt: skip
        self._w.write(self._conns[topic], int(bag_time_ns), self._ts.serialize_ros1(msg, msgtype))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> None:
        """Finish the bag (index, chunk infos)."""
        self._w.close()

    def __enter__(self) -> Bag:
        """Context entry."""
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        """Close on exit."""
        self.close()


def convert_to_mcap(bags: list[Path], out_dir: Path) -> list[Path]:
    """ROS2 MCAP copies (one directory per bag, same stem) of finished ROS1 bags."""
    from rosbags.convert.converter import convert

    humble = get_typestore(Stores.ROS2_HUMBLE)
    out_dir.mkdir(parents=True, exist_ok=True)
    made = []
    for bag in bags:
        dst = out_dir / bag.stem
        convert([bag], dst, "mcap", 9, None, "file", None, humble, [], [], [], [])
        made.append(dst)
    return made
