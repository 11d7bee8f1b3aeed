"""The same synthetic recording in the KITTI-360 raw layout, made from its finished bags.

Layout written under `<root>` for sequence `<seq>` (formats: `ingest.sources.kitti360_calib`):

    data_2d_raw/<seq>/image_0N/data_rect/NNNNNNNNNN.png + image_0N/timestamps.txt
    data_3d_raw/<seq>/velodyne_points/data/NNNNNNNNNN.bin + velodyne_points/timestamps.txt
    data_poses/<seq>/poses.txt (frame + 3x4 T_world_pose) and cam0_to_world.txt (frame + 4x4)
    calibration/perspective.txt, calib_cam_to_velo.txt, calib_cam_to_pose.txt

Conversions (what the release has, what it does not):
- Two perspective cameras: the configured `cameras` map bag camera names to `image_00`/`image_01`.
  Each fisheye JPEG is undistorted (OpenCV fisheye model, the CameraInfo's K and D) into a pinhole
  image at the raw size with K_rect = OpenCV's new camera matrix at `balance` (the ingest's
  `rectify_balance` choice), saved as lossless PNG; P_rect = [K_rect | 0], R_rect = I (the
  rectified camera is the camera frame itself), S_rect = raw width, height. A JPEG that does not
  decode (a corrupt-image fault) is left out: its frame has a stamp and no file.
- The `pose` frame is the bag's base frame; `world` is its odometry frame. poses.txt holds
  T_world_pose at each `image_00` frame inside the odometry span (linear position, slerp, from
  the bag's odometry), so frames before the first or after the last odometry sample have no
  row, as KITTI-360 leaves frames out.
- Velodyne sweeps: float32 x, y, z, intensity of every point of the cloud; per-point time is
  dropped (the release has none). Each sweep's timestamps.txt line is the cloud's header stamp,
  which is its first point's time in the bags: the reader stamps the sweep there.
- Stamps are written as `YYYY-MM-DD HH:MM:SS.fffffffff` (UTC), exact to the nanosecond.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from packets.poses import F64, compose, interpolate_poses, invert_T, make_T, quat_to_rot
from pipeline.synth.lidar import HESAI_DTYPE
from schemas.config import TopicsConfig
from schemas.errors import DataError

NS = 1_000_000_000
KITTI_CAMERAS = ("image_00", "image_01")


def format_stamp(stamp_ns: int) -> str:
    """int64 ns since the epoch -> `YYYY-MM-DD HH:MM:SS.fffffffff` (UTC)."""
    sec, frac = divmod(int(stamp_ns), NS)
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(sec)) + f".{frac:09d}"


def frame_name(frame: int, ext: str) -> str:
    """File name of frame `frame` (10 digits, zero-padded)."""
    return f"{frame:010d}.{ext}"


def _messages(bags: list[Path], topics: set[str]) -> Iterator[tuple[str, Any]]:
    """(topic, deserialized message) of `topics` in every bag, in log-time order per bag."""
    for bag in bags:
        with AnyReader([bag], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
            conns = [c for c in reader.connections if c.topic in topics]
            if not conns:  # rosbags reads every connection when given none
                continue
            for conn, _, raw in reader.messages(connections=conns):
                yield conn.topic, reader.deserialize(raw, conn.msgtype)


def _stamp_ns(msg: Any) -> int:
    """Header stamp (int64 ns)."""
    return int(msg.header.stamp.sec) * NS + int(msg.header.stamp.nanosec)


def _matrix_text(M: npt.ArrayLike) -> str:
    """Numbers of a matrix, row-major, in full float64 precision (repr)."""
    return " ".join(repr(float(v)) for v in np.asarray(M, dtype=np.float64).ravel())


def static_chain(bags: list[Path], topics: TopicsConfig) -> dict[str, F64]:
    """{frame: T_base_frame (4, 4)} for every frame /tf_static connects to the base frame."""
    parent: dict[str, tuple[str, F64]] = {}
    for _, msg in _messages(bags, {topics.tf_static}):
        for ts in msg.transforms:
            t, q = ts.transform.translation, ts.transform.rotation
            T = make_T(quat_to_rot([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])
            parent[ts.child_frame_id.lstrip("/")] = (ts.header.frame_id.lstrip("/"), T)
    out: dict[str, F64] = {topics.base_frame: np.eye(4)}
    for frame in parent:
        chain: list[F64] = []
        f = frame
        while f in parent and len(chain) <= len(parent):
            chain.append(parent[f][1])
            f = parent[f][0]
        if f == topics.base_frame:
            out[frame] = compose(*reversed(chain)) if len(chain) > 1 else chain[0]
    return out


class _Undistorter:
    """Fisheye JPEG -> pinhole PNG bytes at the raw size (K_rect from OpenCV at `balance`)."""

    def __init__(self, info: Any, balance: float) -> None:
        """Maps from a CameraInfo (K, D equidistant, width, height)."""
        K = np.asarray(info.K, np.float64).reshape(3, 3)
        D = np.asarray(info.D, np.float64).reshape(1, 4)
        self.size = (int(info.width), int(info.height))
        self.K_rect = np.asarray(cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
            K, D, self.size, np.eye(3), balance=balance), dtype=np.float64)  # fmt: skip
        self.maps = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), self.K_rect, self.size,
                                                        cv2.CV_32FC1)  # fmt: skip

    def png(self, jpeg: bytes) -> bytes | None:
        """The undistorted image as PNG bytes (BGR order as OpenCV writes), None if undecodable."""
        img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        if img is None or (img.shape[1], img.shape[0]) != self.size:
            return None
        out = cv2.remap(img, self.maps[0], self.maps[1], cv2.INTER_LINEAR)
        ok, buf = cv2.imencode(".png", out)
        return bytes(buf.tobytes()) if ok else None


def _write_camera(bags: list[Path], topics: TopicsConfig, cam: str, folder: Path,
                  balance: float) -> tuple[F64, tuple[int, int], list[int]]:  # fmt: skip
    """One camera's data_rect PNGs and timestamps.txt; (K_rect, (w, h), stamps ns)."""
    image_t, info_t = topics.image_topic(cam), topics.info_topic(cam)
    info = next((m for _, m in _messages(bags, {info_t})), None)
    if info is None:
        raise DataError(f"no CameraInfo on {info_t} in {[b.name for b in bags]}: camera {cam!r} "
                        "cannot be written in the KITTI-360 layout (it needs P_rect)")
    und = _Undistorter(info, balance)
    (folder / "data_rect").mkdir(parents=True, exist_ok=True)
    stamps: list[int] = []
    for _, msg in _messages(bags, {image_t}):
        png = und.png(np.asarray(msg.data, np.uint8).tobytes())
        if png is not None:
            (folder / "data_rect" / frame_name(len(stamps), "png")).write_bytes(png)
        stamps.append(_stamp_ns(msg))
    (folder / "timestamps.txt").write_text("".join(format_stamp(s) + "\n" for s in stamps))
    return und.K_rect, und.size, stamps


def _write_velodyne(bags: list[Path], topics: TopicsConfig, folder: Path) -> int:
    """Every sweep as a .bin (x, y, z, intensity float32) and its header stamp; the count."""
    (folder / "data").mkdir(parents=True, exist_ok=True)
    stamps: list[int] = []
    for _, msg in _messages(bags, {topics.lidar}):
        if int(msg.point_step) != HESAI_DTYPE.itemsize:
            raise DataError(f"{topics.lidar}: point_step {msg.point_step} is not the Hesai 26")
        n = int(msg.width) * int(msg.height)
        pts = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes()[: n * 26], HESAI_DTYPE)
        rows = np.stack([pts["x"], pts["y"], pts["z"], pts["intensity"]], axis=1)
        (folder / "data" / frame_name(len(stamps), "bin")).write_bytes(
            np.ascontiguousarray(rows, dtype="<f4").tobytes())  # fmt: skip
        stamps.append(_stamp_ns(msg))
    (folder / "timestamps.txt").write_text("".join(format_stamp(s) + "\n" for s in stamps))
    return len(stamps)


def _odometry(bags: list[Path], topics: TopicsConfig) -> tuple[npt.NDArray[np.int64], F64, F64]:
    """Odometry stamps (M,) ns, positions (M, 3), quaternions (M, 4) x, y, z, w, stamp order."""
    rows = []
    for _, msg in _messages(bags, {topics.odometry}):
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        rows.append((_stamp_ns(msg), [p.x, p.y, p.z], [q.x, q.y, q.z, q.w]))
    rows.sort(key=lambda r: r[0])
    keep = [r for i, r in enumerate(rows) if i == 0 or r[0] > rows[i - 1][0]]
    return (np.array([r[0] for r in keep], np.int64), np.array([r[1] for r in keep], np.float64),
            np.array([r[2] for r in keep], np.float64))  # fmt: skip


def _write_poses(folder: Path, stamps: list[int], odom: tuple[Any, F64, F64],
                 T_pose_cam0: F64) -> int:  # fmt: skip
    """poses.txt and cam0_to_world.txt at the image_00 frames inside the odometry span."""
    t, pos, quat = odom
    span = int(np.diff(t).max(initial=0)) + 1
    got = interpolate_poses(t, pos, quat, np.asarray(stamps, np.int64), span)
    folder.mkdir(parents=True, exist_ok=True)
    poses, cams = [], []
    for frame in np.flatnonzero(got.ok):
        T = got.T[frame]
        poses.append(f"{frame} {_matrix_text(T[:3])}\n")
        cams.append(f"{frame} {_matrix_text(T @ T_pose_cam0)}\n")
    (folder / "poses.txt").write_text("".join(poses))
    (folder / "cam0_to_world.txt").write_text("".join(cams))
    return len(poses)


def bags_to_kitti360(bags: list[Path], root: Path, topics: TopicsConfig, cameras: list[str],
                     seq: str, balance: float = 0.0) -> dict[str, int]:  # fmt: skip
    """Write the KITTI-360 layout of a mission's bags under `root` (see the module docstring).

    `cameras` (one or two bag camera names) become image_00, image_01 in that order. Returns the
    frames written per sensor folder and the pose rows.
    """
    if not 1 <= len(cameras) <= len(KITTI_CAMERAS):
        raise DataError(f"KITTI-360 holds 1 or 2 perspective cameras, got {cameras}")
    T_base = static_chain(bags, topics)
    counts: dict[str, int] = {}
    persp, to_pose = [], []
    stamps0: list[int] = []
    for cam, name in zip(cameras, KITTI_CAMERAS, strict=False):
        frame = topics.frame_of(cam)
        if frame not in T_base:
            raise DataError(f"/tf_static does not connect {frame!r} to {topics.base_frame!r}")
        K, (w, h), stamps = _write_camera(bags, topics, cam, root / "data_2d_raw" / seq / name,
                                          balance)  # fmt: skip
        stamps0 = stamps0 or stamps
        nn = name[-2:]
        P = np.hstack([K, np.zeros((3, 1))])
        persp += [f"P_rect_{nn}: {_matrix_text(P)}", f"R_rect_{nn}: {_matrix_text(np.eye(3))}",
                  f"S_rect_{nn}: {w} {h}"]  # fmt: skip
        to_pose.append(f"{name}: {_matrix_text(T_base[frame][:3])}")
        counts[name] = len(stamps)
    if topics.lidar_frame not in T_base:
        raise DataError(f"/tf_static does not connect {topics.lidar_frame!r} to "
                        f"{topics.base_frame!r}")  # fmt: skip
    counts["velodyne_points"] = _write_velodyne(bags, topics,
                                                root / "data_3d_raw" / seq / "velodyne_points")
    T_cam0 = T_base[topics.frame_of(cameras[0])]
    calib = root / "calibration"
    calib.mkdir(parents=True, exist_ok=True)
    (calib / "perspective.txt").write_text("\n".join(persp) + "\n")
    (calib / "calib_cam_to_pose.txt").write_text("\n".join(to_pose) + "\n")
    T_velo_cam0 = invert_T(T_base[topics.lidar_frame]) @ T_cam0
    (calib / "calib_cam_to_velo.txt").write_text(_matrix_text(T_velo_cam0[:3]) + "\n")
    counts["poses"] = _write_poses(root / "data_poses" / seq, stamps0, _odometry(bags, topics),
                                   T_cam0)  # fmt: skip
    return counts
