"""Tiny GrandTour-like missions written in the test with rosbags' ROS1 writer (Noetic typestore).

One bag per sensor group: `<m>_hdr_<cam>.bag` (CompressedImage + CameraInfo), `<m>_hesai.bag`
(PointCloud2 with the Hesai layout: x, y, z, intensity float32, ring uint16, timestamp float64
at offset 18, point_step 26), `<m>_tf_minimal.bag` (/tf_static) and `<m>_anymal_state.bag`
(nav_msgs/Odometry). Faults are switched on by keyword.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from packets.poses import F64, make_T, rot_to_quat

T0_NS = 1_700_000_000_000_000_000
CAM_W, CAM_H = 96, 64
K_RAW = np.array([[40.0, 0, 47.5], [0, 40.0, 31.5], [0, 0, 1]])
D_RAW = np.array([0.02, -0.01, 0.003, -0.001])


def typestore() -> Any:
    """ROS1 Noetic types plus tf2_msgs/msg/TFMessage."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(
        get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
    )
    return ts


def _rot(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> F64:
    cy, sy, cp, sp, cr, sr = (np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch),
                              np.cos(roll), np.sin(roll))  # fmt: skip
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return Rz @ Ry @ Rx


# Static tree (parent, child, T_parent_child). Camera optical frame: z forward = base x.
R_OPT = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
STATIC_EDGES: list[tuple[str, str, F64]] = [
    ("base", "box_base", make_T(_rot(0.05), [0.2, 0.0, 0.3])),
    ("box_base", "hdr_base", make_T(_rot(0.0, 0.02), [0.1, 0.0, 0.05])),
    ("hdr_base", "hdr_front", make_T(R_OPT @ _rot(0.0, 0.0, 0.01), [0.05, 0.0, 0.0])),
    # inverted edge: the LiDAR published as the parent of box_base
    ("hesai_lidar", "box_base", make_T(_rot(-0.1), [0.0, 0.0, -0.15])),
]


def odom_pose(t_s: float) -> F64:
    """Ground-truth T_odom_base at time t (seconds since start): forward 1 m/s, slow yaw."""
    return make_T(_rot(0.3 * t_s), [1.0 * t_s, 0.1 * t_s, 0.0])


@dataclass
class Mission:
    """Knobs of a tiny mission (seconds, rates, faults)."""

    seconds: float = 1.0
    camera_hz: float = 10.0
    lidar_hz: float = 10.0
    odom_hz: float = 20.0
    cameras: tuple[str, ...] = ("front",)
    points: int = 200
    camera_offset_ns: int = 13_000_000
    corrupt_jpeg_at: set[int] = field(default_factory=set)
    duplicate_image_at: set[int] = field(default_factory=set)
    swap_images_at: set[int] = field(default_factory=set)
    empty_sweep_at: set[int] = field(default_factory=set)
    nan_points: int = 0
    odom_gap_s: tuple[float, float] | None = None
    no_camera_info: set[str] = field(default_factory=set)
    drop_edge: str | None = None
    truncate_lidar_bytes: int = 0
    bad_pose_at: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    zero_focal: set[str] = field(default_factory=set)
    nan_rows: int = 0  # leading points of every sweep with x, y and z NaN (missing returns)
    dense: bool = False  # the clouds' is_dense flag
    invalid: str = "nan"  # how the nan_rows points mark a missing return (INVALID_STYLES)
    zero_times: bool = False  # every point's timestamp 0.0 (no point-time convention fits)
    ring_order: str = "elevation"  # "random" (or "random_from_10": from sweep 10 on): ring
    # numbers that do not index elevation
    field_offsets: dict[str, int] = field(default_factory=dict)  # declared offsets that differ
    # from the bytes' (a layout that contradicts its contract); the bytes stay the Hesai layout


def _header(ts: Any, stamp: int, frame: str) -> Any:
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    return Header(seq=0, stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=frame)


def _image(i: int) -> np.ndarray:
    yy, xx = np.mgrid[0:CAM_H, 0:CAM_W]
    img = np.stack([(xx * 5 + i) % 256, (yy * 7) % 256, ((xx // 8 + yy // 8) % 2) * 200], -1)
    return img.astype(np.uint8)


def _jpeg(i: int) -> np.ndarray:
    ok, buf = cv2.imencode(".jpg", _image(i), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return np.asarray(buf, dtype=np.uint8).ravel()


def _write(path: Path, msgs: list[tuple[str, str, int, Any]], ts: Any, lz4: bool = True) -> None:
    """Write (topic, type, log time, message) in list order to a ROS1 bag (LZ4, 64 kB chunks)."""
    w = Writer(path)
    if lz4:
        w.set_compression(Writer.CompressionFormat.LZ4)
    w.chunk_threshold = 64 * 1024
    with w:
        conns: dict[str, Any] = {}
        for topic, typ, t, msg in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=ts)
            w.write(conns[topic], t, ts.serialize_ros1(msg, typ))


def camera_stamps(m: Mission) -> list[int]:
    """Image header stamps (ns) before faults."""
    n = round(m.seconds * m.camera_hz)
    return [T0_NS + m.camera_offset_ns + round(i * 1e9 / m.camera_hz) for i in range(n)]


def lidar_stamps(m: Mission) -> list[int]:
    """Sweep header stamps (ns)."""
    n = round(m.seconds * m.lidar_hz)
    return [T0_NS + round(i * 1e9 / m.lidar_hz) for i in range(n)]


def write_camera(d: Path, name: str, m: Mission, cam: str, ts: Any) -> None:
    """Images (with faults) and CameraInfo of one camera."""
    CI, CImg = ts.types["sensor_msgs/msg/CameraInfo"], ts.types["sensor_msgs/msg/CompressedImage"]
    RoI = ts.types["sensor_msgs/msg/RegionOfInterest"]
    msgs: list[tuple[str, str, int, Any]] = []
    stamps = camera_stamps(m)
    for i, st in enumerate(stamps):
        stamp = (
            stamps[i + 1]
            if i in m.swap_images_at
            else stamps[i - 1]
            if i - 1 in m.swap_images_at
            else st
        )
        data = _jpeg(i)
        if i in m.corrupt_jpeg_at:
            data = data[: data.size // 2]
        img = CImg(header=_header(ts, stamp, f"hdr_{cam}"), format="jpeg", data=data)
        msgs.append((f"/boxi/hdr/{cam}/image_raw/compressed", "sensor_msgs/msg/CompressedImage",
                     st, img))  # fmt: skip
        if i in m.duplicate_image_at:
            msgs.append((msgs[-1][0], msgs[-1][1], st + 1, img))
        if cam not in m.no_camera_info:
            K = K_RAW.copy()
            if cam in m.zero_focal:
                K[0, 0] = 0.0
            info = CI(header=_header(ts, st, f"hdr_{cam}"), height=CAM_H, width=CAM_W,
                      distortion_model="equidistant", D=D_RAW.copy(), K=K.ravel(),
                      R=np.eye(3).ravel(), P=np.zeros(12), binning_x=0, binning_y=0,
                      roi=RoI(x_offset=0, y_offset=0, height=0, width=0,
                              do_rectify=False))  # fmt: skip
            msgs.append((f"/boxi/hdr/{cam}/camera_info", "sensor_msgs/msg/CameraInfo", st, info))
    _write(d / f"{name}_hdr_{cam}.bag", msgs, ts)


HESAI_DTYPE = np.dtype(
    {
        "names": ["x", "y", "z", "intensity", "ring", "timestamp"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f8"],
        "offsets": [0, 4, 8, 12, 16, 18],
        "itemsize": 26,
    }
)


def sweep_points(i: int, n: int, nan_points: int = 0) -> np.ndarray:
    """Points of sweep i in the LiDAR frame (structured HESAI_DTYPE, timestamp filled later)."""
    rng = np.random.default_rng(i)
    pts = np.zeros(n, dtype=HESAI_DTYPE)
    ang = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(2.0, 10.0, n)
    pts["x"], pts["y"], pts["z"] = r * np.cos(ang), r * np.sin(ang), rng.uniform(-1, 1, n)
    pts["intensity"] = rng.uniform(0, 255, n)
    pts["ring"] = rng.integers(0, 32, n)
    if nan_points:  # NaN rows (missing returns), then as many points at zero
        for c in ("x", "y", "z"):
            pts[c][:nan_points] = np.nan
        pts["y"][nan_points : 2 * nan_points] = 0.0
        pts["x"][nan_points : 2 * nan_points] = 0.0
        pts["z"][nan_points : 2 * nan_points] = 0.0
    return pts


INVALID_STYLES = {"nan": (np.nan,) * 3, "x_nan": (np.nan, 0.0, 0.0),
                  "posinf": (np.inf,) * 3, "neginf": (-np.inf,) * 3, "zero": (0.0,) * 3}
"""Conventions of drivers for a missing return: (x, y, z) written for it."""


def mark_invalid(pts: np.ndarray, style: str) -> None:
    """Write the missing-return convention `style` (INVALID_STYLES) into points, in place."""
    for c, v in zip(("x", "y", "z"), INVALID_STYLES[style], strict=True):
        pts[c] = v


def spin_like(pts: np.ndarray, stamp_ns: int) -> None:
    """Times and rings of a spinning sensor (ingest's plausibility checks): each point fired
    when the rotation passed its azimuth (the sweep spans 0.09 s from the header stamp), its
    ring the 1-degree elevation bin."""
    x, y, z = (np.nan_to_num(pts[c].astype(np.float64)) for c in ("x", "y", "z"))
    az = np.arctan2(y, x)
    span = float(np.ptp(az)) if az.size else 0.0
    pts["timestamp"] = stamp_ns / 1e9 + ((az - az.min()) / span * 0.09 if span else 0.0)
    pts["ring"] = np.clip(np.floor(np.degrees(np.arctan2(z, np.hypot(x, y)))) + 32, 0, 63)


def write_lidar(d: Path, name: str, m: Mission, ts: Any) -> None:
    """PointCloud2 sweeps with the Hesai layout (unaligned float64 timestamp)."""
    PC2, PF = ts.types["sensor_msgs/msg/PointCloud2"], ts.types["sensor_msgs/msg/PointField"]
    fields = [PF(name=n, offset=m.field_offsets.get(n, o), datatype=dt, count=1) for n, o, dt in
              [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7), ("ring", 16, 4),
               ("timestamp", 18, 8)]]  # fmt: skip
    msgs = []
    for i, st in enumerate(lidar_stamps(m)):
        n = 0 if i in m.empty_sweep_at else m.points
        pts = sweep_points(i, n, m.nan_points)
        spin_like(pts, st)
        if m.ring_order == "random" or (m.ring_order == "random_from_10" and i >= 10):
            pts["ring"] = np.random.default_rng(i).integers(0, 32, n)
        mark_invalid(pts[: m.nan_rows], m.invalid)
        if m.zero_times:
            pts["timestamp"] = 0.0
        pc = PC2(header=_header(ts, st, "hesai_lidar"), height=1, width=n, fields=fields,
                 is_bigendian=False, point_step=26, row_step=26 * n,
                 data=np.frombuffer(pts.tobytes(), np.uint8), is_dense=m.dense)  # fmt: skip
        msgs.append(("/boxi/hesai/points_undistorted", "sensor_msgs/msg/PointCloud2", st, pc))
    path = d / f"{name}_hesai_undist.bag"
    _write(path, msgs, ts)
    if m.truncate_lidar_bytes:
        data = path.read_bytes()
        path.write_bytes(data[: m.truncate_lidar_bytes])


def write_tf_odom(d: Path, name: str, m: Mission, ts: Any) -> None:
    """/tf_static (with one inverted edge) and odometry."""
    TFM, TS = ts.types["tf2_msgs/msg/TFMessage"], ts.types["geometry_msgs/msg/TransformStamped"]
    Tr, V3, Q = (ts.types[f"geometry_msgs/msg/{k}"] for k in ("Transform", "Vector3", "Quaternion"))
    tfs = []
    for parent, child, T in STATIC_EDGES:
        if child == m.drop_edge:
            continue
        q = rot_to_quat(T[:3, :3])
        tr = Tr(translation=V3(x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                rotation=Q(x=q[0], y=q[1], z=q[2], w=q[3]))  # fmt: skip
        tfs.append(TS(header=_header(ts, T0_NS, parent), child_frame_id=child, transform=tr))
    msgs = [("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS, TFM(transforms=tfs))]
    _write(d / f"{name}_tf_minimal.bag", msgs, ts)
    Odo = ts.types["nav_msgs/msg/Odometry"]
    PWC, TWC = (
        ts.types["geometry_msgs/msg/PoseWithCovariance"],
        ts.types["geometry_msgs/msg/TwistWithCovariance"],
    )
    Pose, Pt, Tw = (ts.types[f"geometry_msgs/msg/{k}"] for k in ("Pose", "Point", "Twist"))
    odo = []
    n = round((m.seconds + 0.2) * m.odom_hz)
    for i in range(-2, n):
        t_s = i / m.odom_hz
        if m.odom_gap_s and m.odom_gap_s[0] < t_s < m.odom_gap_s[1]:
            continue
        T = odom_pose(t_s)
        q = rot_to_quat(T[:3, :3])
        st = T0_NS + round(i * 1e9 / m.odom_hz)
        x, y, z = m.bad_pose_at.get(i, (T[0, 3], T[1, 3], T[2, 3]))
        pose = Pose(
            position=Pt(x=x, y=y, z=z),
            orientation=Q(x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        msg = Odo(header=_header(ts, st, "odom"), child_frame_id="base",
                  pose=PWC(pose=pose, covariance=np.zeros(36)),
                  twist=TWC(twist=Tw(linear=V3(x=0, y=0, z=0), angular=V3(x=0, y=0, z=0)),
                            covariance=np.zeros(36)))  # fmt: skip
        odo.append(("/anymal/state_estimator/odometry", "nav_msgs/msg/Odometry", st, msg))
    _write(d / f"{name}_anymal_state.bag", odo, ts)


def write_mission(root: Path, m: Mission | None = None, name: str = "m0") -> Path:
    """A mission folder `root/name` with all bags; returns its path."""
    m = m or Mission()
    d = root / name
    d.mkdir(parents=True)
    ts = typestore()
    for cam in m.cameras:
        write_camera(d, name, m, cam, ts)
    write_lidar(d, name, m, ts)
    write_tf_odom(d, name, m, ts)
    return d


def gt_T_base(frame: str) -> F64:
    """Ground-truth T_base_frame from STATIC_EDGES (independent small solver)."""
    edges: dict[str, tuple[str, F64]] = {}
    for parent, child, T in STATIC_EDGES[:3]:  # the fourth edge is the inverted one
        edges[child] = (parent, T)
    if frame == "hesai_lidar":  # base<-box_base<-(inverse of hesai_lidar->box_base)
        return gt_T_base("box_base") @ np.linalg.inv(STATIC_EDGES[3][2])
    T = np.eye(4)
    node = frame
    while node != "base":
        parent, Tpc = edges[node]
        T = Tpc @ T
        node = parent
    return T
