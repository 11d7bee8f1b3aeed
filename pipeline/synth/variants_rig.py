"""Rig variants of a synthetic recording: cameras, image encodings and folder layouts that real
robots write and the default recording does not.

The sensor variants (`variants.VARIANTS`) change a sensor while the mission is written; these
change a written ROS1 mission (or its config) afterwards, so each applies on top of any sensor
variant. `RIG_VARIANTS` maps each name to its description; the functions:

- `rig_topics(cameras)`: per-camera topics and frames outside the `{camera}` templates (as
  GrandTour's ten cameras: five Alphasense, three HDR, two ZED2i), for `synth.cameras` of any
  names (`TEN_CAMERAS`);
- `to_raw_images`: every CompressedImage JPEG rewritten as a sensor_msgs/Image in one raw
  encoding (rgb8, bgr8, rgba8, bgra8, mono8, mono16, bayer_* 8/16; `step` padded by
  `pad_bytes`, 16-bit big endian on request), or as a PNG CompressedImage (`png`);
- `change_camera_info`: from a time on, one camera's images at another resolution with their
  CameraInfo scaled to match (a driver restarted with binning);
- `split_bags`: every bag cut in time into `<name>_0.bag`, `<name>_1.bag`, ...;
- `to_rosbag2_folder`: the mission folder itself made a rosbag2 folder (`metadata.yaml`
  inside), one MCAP file per original bag (several storage files in one bag);
- `add_lidar`: a second LiDAR: every sweep of the first also on its own topic, its points in
  its own frame (a static TF edge from the first LiDAR's frame; a test fixture: the same
  points twice). The `two_lidars` variant is written by the generator itself
  (`synth.second_lidar`: another mount, other points, other times);
- `odometry_as`: every nav_msgs/Odometry rewritten as a geometry_msgs/PoseStamped or
  PoseWithCovarianceStamped (the same pose and header; no child frame, no twist).
"""

from __future__ import annotations

import copy
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from rosbags.rosbag1 import Reader, Writer
from rosbags.typesys import Stores, get_typestore

from pipeline.synth.rosio import ros1_typestore as ros1_typestore
from pipeline.synth.rosio import set_chunk_compression
from schemas.config import CameraTopics

RIG_VARIANTS: dict[str, str] = {
    "camera_names": "cameras named outside front/left/right, own topics and frames",
    "ten_cameras": "a ten-camera rig (GrandTour: five Alphasense, three HDR, two ZED2i)",
    "raw_images": "sensor_msgs/Image in a raw encoding (rgb8 ... bayer_grbg16)",
    "png_images": "CompressedImage PNG",
    "camera_info_change": "one camera's resolution and K change mid-recording",
    "split_bags": "every bag split in time (<name>_0.bag, <name>_1.bag)",
    "rosbag2_folder": "the mission folder is itself a rosbag2 folder of several MCAP files",
    "pose_stamped": "odometry as geometry_msgs/PoseStamped",
    "pose_with_covariance": "odometry as geometry_msgs/PoseWithCovarianceStamped",
    "two_lidars": "a second LiDAR mounted elsewhere (synth.second_lidar), both merged into "
                  "the packets",
}
"""Every rig variant by name (applied by the functions of this module)."""

TEN_CAMERAS = ("alphasense_front_center", "alphasense_front_left", "alphasense_front_right",
               "alphasense_left", "alphasense_right", "hdr_front", "hdr_left", "hdr_right",
               "zed2i_left", "zed2i_right")  # fmt: skip
"""GrandTour's cameras (ten names no single `{camera}` template covers)."""

IMAGE_RAW_T = "sensor_msgs/msg/Image"
COMPRESSED_T = "sensor_msgs/msg/CompressedImage"
INFO_T = "sensor_msgs/msg/CameraInfo"
ODOMETRY_T = "nav_msgs/msg/Odometry"
POSE_T = "geometry_msgs/msg/PoseStamped"
POSE_COV_T = "geometry_msgs/msg/PoseWithCovarianceStamped"
BAYER_SITES = {"rggb": ((0, 0), (0, 1), (1, 1)), "bggr": ((1, 1), (0, 1), (0, 0)),
               "gbrg": ((1, 0), (0, 0), (0, 1)), "grbg": ((0, 1), (0, 0), (1, 0))}  # fmt: skip
"""(row, col) within a 2x2 tile of the R, one G and B sample of each Bayer pattern."""


def rig_topics(cameras: list[str]) -> dict[str, CameraTopics]:
    """Per-camera topics and frames in the drivers' styles (Alphasense, HDR, ZED2i, other)."""
    out = {}
    for cam in cameras:
        family, _, rest = cam.partition("_")
        if family == "alphasense":
            base = f"/gt_box/alphasense_driver_node/{rest}"
            out[cam] = CameraTopics(image=f"{base}/color/image/compressed",
                                    info=f"{base}/color/camera_info", frame=f"{cam}_sensor")
        elif family == "zed2i":
            base = f"/gt_box/zed2i/zed_node/{rest}"
            out[cam] = CameraTopics(image=f"{base}/image_rect_color/compressed",
                                    info=f"{base}/camera_info", frame=f"zed2i_{rest}_optical")
        else:
            out[cam] = CameraTopics(image=f"/rig/{cam}/image/compressed",
                                    info=f"/rig/{cam}/camera_info", frame=f"{cam}_optical")
    return out


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """(H, W) Bayer mosaic of an (H, W, 3) RGB image (H, W even) in `pattern` (rggb, ...)."""
    out = np.zeros(rgb.shape[:2], dtype=rgb.dtype)
    r, g, b = BAYER_SITES[pattern]
    g2 = (1 - g[0], 1 - g[1])
    for (y, x), c in ((r, 0), (g, 1), (g2, 1), (b, 2)):
        out[y::2, x::2] = rgb[y::2, x::2, c]
    return out


def raw_pixels(rgb: np.ndarray, encoding: str, big_endian: bool = False) -> tuple[bytes, int]:
    """(row bytes, bytes per row) of an (H, W, 3) uint8 RGB image in a raw `encoding`; 16-bit
    encodings carry value x 257 (so value >> 8 gives the 8-bit value back)."""
    depth16 = encoding.endswith("16")
    if encoding.startswith("bayer_"):
        px = mosaic(rgb, encoding[6:10])[..., None]
    elif encoding.startswith("mono"):
        px = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[..., None]
    else:
        order = {"rgb8": [0, 1, 2], "bgr8": [2, 1, 0], "rgba8": [0, 1, 2, 3],
                 "bgra8": [2, 1, 0, 3]}[encoding]  # fmt: skip
        rgba = np.concatenate([rgb, np.full((*rgb.shape[:2], 1), 255, np.uint8)], axis=2)
        px = rgba[..., order]
    if depth16:
        px = px.astype(np.uint16) * 257
        px = px.astype(">u2" if big_endian else "<u2")
    rows = np.ascontiguousarray(px).reshape(rgb.shape[0], -1).view(np.uint8)
    return rows.tobytes(), rows.shape[1]


def _plain_writer(path: Path) -> Writer:
    """A ROS1 writer of uncompressed chunks (no checksum: every message is judged)."""
    writer = Writer(path)
    set_chunk_compression(writer, "none")
    return writer


def _bgr(data: Any) -> np.ndarray:
    """(H, W, 3) BGR of the intact JPEG bytes the generator wrote."""
    img = cv2.imdecode(np.asarray(data, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "the generator's JPEG does not decode"
    return np.asarray(img, dtype=np.uint8)


def _messages(bag: Path) -> Iterator[tuple[Any, int, bytes]]:
    with Reader(bag) as reader:
        yield from reader.messages()


def rewrite_bag(bag: Path, convert: Any) -> None:
    """Rewrite one ROS1 bag in place; `convert(topic, msgtype, stamp, raw)` returns (topic,
    msgtype, raw), a list of them (written in order), or None to keep the message as it is."""
    ts = ros1_typestore()
    tmp = bag.with_name(f".{bag.name}.rig")
    writer = _plain_writer(tmp)
    conns: dict[tuple[str, str], Any] = {}
    with writer:
        for conn, stamp, raw in _messages(bag):
            got = convert(conn.topic, conn.msgtype, stamp, raw) or (conn.topic, conn.msgtype, raw)
            for topic, msgtype, data in got if isinstance(got, list) else [got]:
                if (topic, msgtype) not in conns:
                    latch = 1 if topic.endswith("tf_static") else None
                    conns[(topic, msgtype)] = writer.add_connection(topic, msgtype, typestore=ts,
                                                                    latching=latch)  # fmt: skip
                writer.write(conns[(topic, msgtype)], stamp, data)
    tmp.replace(bag)


def to_raw_images(mission: Path, encoding: str, pad_bytes: int = 0,
                  big_endian: bool = False) -> None:  # fmt: skip
    """Rewrite every CompressedImage of the mission as `encoding` (a raw encoding, or `png`)."""
    ts = ros1_typestore()

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        if msgtype != COMPRESSED_T:
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        bgr = _bgr(msg.data)
        if encoding == "png":
            png = np.asarray(cv2.imencode(".png", bgr)[1], np.uint8).ravel()
            out = ts.types[COMPRESSED_T](header=msg.header, format="png", data=png)
            return topic, COMPRESSED_T, ts.serialize_ros1(out, COMPRESSED_T)
        rows, row_bytes = raw_pixels(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), encoding, big_endian)
        h, w = bgr.shape[:2]
        data = np.frombuffer(rows, np.uint8).reshape(h, row_bytes)
        data = np.concatenate([data, np.full((h, pad_bytes), 0xAB, np.uint8)], axis=1)
        img = ts.types[IMAGE_RAW_T](header=msg.header, height=h, width=w, encoding=encoding,
                                    is_bigendian=int(big_endian), step=row_bytes + pad_bytes,
                                    data=data.ravel())  # fmt: skip
        return topic.removesuffix("/compressed"), IMAGE_RAW_T, ts.serialize_ros1(img, IMAGE_RAW_T)

    for bag in sorted(mission.glob("*_hdr_*.bag")):
        rewrite_bag(bag, convert)


def change_camera_info(mission: Path, camera_bag: str, from_ns: int, scale: float = 0.5) -> int:
    """From header stamp `from_ns` on, the images of one camera bag (`<mission>_<camera_bag>
    .bag`) resized by `scale` (JPEG re-encoded) and their CameraInfo scaled to match (K in
    pixel-centre convention; D unchanged: the same lens). Returns the images changed."""
    ts = ros1_typestore()
    changed = 0

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        nonlocal changed
        if msgtype not in (COMPRESSED_T, INFO_T):
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        head = int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)
        if head < from_ns:
            return None
        if msgtype == INFO_T:
            K = np.asarray(msg.K, np.float64).reshape(3, 3).copy()
            K[:2, :2] *= scale
            K[:2, 2] = (K[:2, 2] + 0.5) * scale - 0.5
            P = np.asarray(msg.P, np.float64).reshape(3, 4).copy()
            P[:, :3] = K
            msg = ts.types[INFO_T](**{**{k: getattr(msg, k) for k in msg.__dataclass_fields__},
                                      "K": K.ravel(), "P": P.ravel(),
                                      "width": round(msg.width * scale),
                                      "height": round(msg.height * scale)})  # fmt: skip
        else:
            bgr = _bgr(msg.data)
            h, w = bgr.shape[:2]
            small = cv2.resize(bgr, (round(w * scale), round(h * scale)),
                               interpolation=cv2.INTER_AREA)  # fmt: skip
            jpeg = np.asarray(cv2.imencode(".jpg", small)[1], np.uint8).ravel()
            msg = ts.types[COMPRESSED_T](header=msg.header, format=msg.format, data=jpeg)
            changed += 1
        return topic, msgtype, ts.serialize_ros1(msg, msgtype)

    rewrite_bag(next(mission.glob(f"*_{camera_bag}.bag")), convert)
    return changed


def odometry_as(mission: Path, msgtype: str) -> int:
    """Rewrite every nav_msgs/Odometry message of the mission as `msgtype` (POSE_T or
    POSE_COV_T): the same header and pose (the covariance too), on the same topic. The child
    frame is dropped: a pose message has none (the generator's child is the base frame).
    Returns the messages rewritten."""
    ts = ros1_typestore()
    m = ts.types
    done = 0

    def convert(topic: str, mtype: str, stamp: int, raw: bytes) -> Any:
        nonlocal done
        if mtype != ODOMETRY_T:
            return None
        odo = ts.deserialize_ros1(raw, mtype)
        if msgtype == POSE_T:
            out = m[POSE_T](header=odo.header, pose=odo.pose.pose)
        else:
            out = m[POSE_COV_T](header=odo.header, pose=odo.pose)
        done += 1
        return topic, msgtype, ts.serialize_ros1(out, msgtype)

    for bag in sorted(mission.glob("*.bag")):
        with Reader(bag) as reader:
            if not any(c.msgtype == ODOMETRY_T for c in reader.connections):
                continue
        rewrite_bag(bag, convert)
    return done


def add_lidar(mission: Path, first: tuple[str, str], second: tuple[str, str],
              T_first_second: np.ndarray, every: int = 1) -> int:  # fmt: skip
    """A second LiDAR (topic, frame) mounted at `T_first_second` (4, 4: its pose in the first
    LiDAR's frame, m): after every `every`-th PointCloud2 of the `first` (topic, frame) the
    same sweep on the second topic (`every` 2: at half the rate), x, y, z in the second frame
    (same stamp, other fields as written), and the static edge first frame -> second frame
    added to /tf_static. Returns the sweeps copied."""
    ts = ros1_typestore()
    T_second_first = np.linalg.inv(np.asarray(T_first_second, dtype=np.float64))
    copied = 0
    seen = [0]

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        nonlocal copied
        if topic.endswith("tf_static"):
            return topic, msgtype, ts.serialize_ros1(_with_edge(ts.deserialize_ros1(raw, msgtype),
                                                                first[1], second[1],
                                                                T_first_second), msgtype)
        if topic != first[0]:
            return None
        seen[0] += 1
        if (seen[0] - 1) % every:
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        msg.data = _moved_points(msg, T_second_first)
        msg.header.frame_id = second[1]
        copied += 1
        return [(topic, msgtype, raw), (second[0], msgtype, ts.serialize_ros1(msg, msgtype))]

    for bag in sorted(mission.glob("*.bag")):
        rewrite_bag(bag, convert)
    return copied


def _moved_points(cloud: Any, T: np.ndarray) -> np.ndarray:
    """The cloud's bytes with x, y, z (float32) mapped by T (4, 4); other fields unchanged."""
    offs = {f.name: int(f.offset) for f in cloud.fields}
    step, n = int(cloud.point_step), int(cloud.width) * int(cloud.height)
    data = np.array(cloud.data, dtype=np.uint8)
    rows = data[: n * step].reshape(n, step)
    xyz = np.stack([rows[:, offs[k]:offs[k] + 4].copy().view("<f4")[:, 0] for k in "xyz"], 1)
    moved = (xyz.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype("<f4")
    for j, k in enumerate("xyz"):
        rows[:, offs[k]:offs[k] + 4] = moved[:, j:j + 1].view(np.uint8)
    return data


def _with_edge(tf: Any, parent: str, child: str, T: np.ndarray) -> Any:
    """A TFMessage with the edge parent -> child (child coordinates into parent: T) added,
    stamped as its first transform."""
    from packets.poses import rot_to_quat

    edge = copy.deepcopy(tf.transforms[0])
    edge.header.frame_id, edge.child_frame_id = parent, child
    tr, q = edge.transform.translation, edge.transform.rotation
    tr.x, tr.y, tr.z = (float(v) for v in T[:3, 3])
    q.x, q.y, q.z, q.w = (float(v) for v in rot_to_quat(T[:3, :3]))
    tf.transforms = [*tf.transforms, edge]
    return tf


def split_bags(mission: Path, parts: int = 2) -> None:
    """Cut every bag of the mission in time into `parts` bags `<name>_<i>.bag` (equal spans
    of log time; latched /tf_static stays in the first)."""
    ts = ros1_typestore()
    for bag in sorted(mission.glob("*.bag")):
        with Reader(bag) as reader:
            t0, t1 = reader.start_time, reader.end_time
        # int64 edges: float64 rounds ns epochs to 256 ns, which could put t0 before edge 0
        edges = t0 + (np.arange(parts + 1, dtype=np.int64) * (t1 + 1 - t0)) // parts
        writers: list[Writer] = []
        conns: list[dict[str, Any]] = []
        for i in range(parts):
            w = _plain_writer(bag.with_name(f"{bag.stem}_{i}.bag"))
            w.open()
            writers.append(w)
            conns.append({})
        for conn, stamp, raw in _messages(bag):
            i = min(max(int(np.searchsorted(edges, stamp, side="right")) - 1, 0), parts - 1)
            if conn.topic not in conns[i]:
                latch = 1 if conn.topic.endswith("tf_static") else None
                conns[i][conn.topic] = writers[i].add_connection(
                    conn.topic, conn.msgtype, typestore=ts, latching=latch)
            writers[i].write(conns[i][conn.topic], stamp, raw)
        for w in writers:
            w.close()
        bag.unlink()


def to_rosbag2_folder(mission: Path) -> list[str]:
    """Make the mission folder itself one rosbag2 bag: each ROS1 bag converted to an MCAP file,
    all of them listed in one `metadata.yaml` (several storage files of one bag). Returns the
    storage file names."""
    from rosbags.convert.converter import convert

    humble = get_typestore(Stores.ROS2_HUMBLE)
    work = mission / ".rosbag2"
    shutil.rmtree(work, ignore_errors=True)
    metas, files = [], []
    for bag in sorted(mission.glob("*.bag")):
        dst = work / bag.stem
        convert([bag], dst, "mcap", 9, None, "file", None, humble, [], [], [], [])
        meta = yaml.safe_load((dst / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        for rel in meta["relative_file_paths"]:
            (dst / rel).replace(mission / rel)
            files.append(rel)
        metas.append(meta)
        bag.unlink()
    shutil.rmtree(work)
    (mission / "metadata.yaml").write_text(yaml.safe_dump(
        {"rosbag2_bagfile_information": _merged_metadata(metas, files)}))
    return files


def _merged_metadata(metas: list[dict[str, Any]], files: list[str]) -> dict[str, Any]:
    """One rosbag2 metadata of several converted bags (their files, topics, counts, span)."""
    start = min(m["starting_time"]["nanoseconds_since_epoch"] for m in metas)
    end = max(m["starting_time"]["nanoseconds_since_epoch"] + m["duration"]["nanoseconds"]
              for m in metas)  # fmt: skip
    topics: dict[str, dict[str, Any]] = {}
    for m in metas:
        for t in m["topics_with_message_count"]:
            name = t["topic_metadata"]["name"]
            if name in topics:
                topics[name]["message_count"] += t["message_count"]
            else:
                topics[name] = dict(t)
    out = dict(metas[0])
    out.update(relative_file_paths=files, message_count=sum(m["message_count"] for m in metas),
               starting_time={"nanoseconds_since_epoch": start},
               duration={"nanoseconds": end - start},
               topics_with_message_count=list(topics.values()),
               files=[f for m in metas for f in m.get("files", [])])  # fmt: skip
    return out
