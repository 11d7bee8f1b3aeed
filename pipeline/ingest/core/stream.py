"""The streaming pass: each bag read once, messages of the configured topics handled one by one.

Each topic's messages are fed, as stamped records, to its gated pass (`gated_pass.GatedPass`,
the ingest core every source uses: stamp gate, handler, fitted checks, rejects, accounting),
across the bags of the recording. The handlers: images decoded and rectified
(`stream_images`), sweeps decoded for their counts and time span (`sweep_stream`), poses
(`stream_poses`); the state they share is `stream_state`. Nothing is held beyond the current
message and the few the checks wait on (index rows are flushed in batches).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

from packets.poses import rot_to_quat
from pipeline.ingest.core.gated_pass import GatedPass, Handler, Held, Indexed, Record
from pipeline.ingest.core.sinks import CameraImage, ImageSink, Writers
from pipeline.ingest.core.stream_images import image_message
from pipeline.ingest.core.stream_poses import MAX_POSITION_M, odometry_message, pose_row
from pipeline.ingest.core.stream_state import StreamState
from pipeline.ingest.core.sweep_stream import release_held, sweep_message
from pipeline.ingest.errors import BadPoseError, RowReject
from pipeline.ingest.sources.bags import BagFile, Message, stamp_ns
from pipeline.ingest.sources.ros1_scan import MAGIC
from pipeline.ingest.sources.tf_odometry import odom_edges
from schemas.recording_index import Reason

__all__ = ["MAX_POSITION_M", "CameraImage", "ImageSink", "StreamState", "Writers",
           "finish_stream", "report_damage", "stream_bag"]


def stream_bag(bag: BagFile, st: StreamState, out: Writers) -> None:
    """Feed every configured message of one bag to its topic's gated pass; report the bag's
    damaged regions.

    Accounting: every message read is counted in `out.tally` and ends as an index row (kept)
    or a reject row (rejected); a /tf message used as odometry counts once per odom-base edge.
    """
    topics = st.wanted() & set(bag.topics())
    for msg in bag.messages(sorted(topics)):
        if msg.topic in st.info_topics:  # calibration, not data: not in the accounting
            _camera_info(bag, msg, st)
            continue
        st.seen[msg.topic] = st.seen.get(msg.topic, 0) + 1
        gp = topic_pass(msg.topic, st, out)
        for rec in _records(bag, msg, st):
            gp.push(rec)
    passes = [st.passes[t] for t in sorted(topics) if t in st.passes]
    for gp in passes:
        gp.end_gate(bag.name)
    for gp in sorted(st.passes.values(), key=lambda p: st.image_topics.get(p.topic, "")):
        gp.end_holds()  # the images the drift check holds, by camera
    for gp in st.passes.values():
        gp.end_jumps()
    report_damage(bag, out, read=any(f == bag.name for f, _ in out.tally.read))


def topic_pass(topic: str, st: StreamState, out: Writers) -> GatedPass:
    """The gated pass of `topic` (made on its first message): images, sweeps or poses."""
    if topic in st.passes:
        return st.passes[topic]
    if topic in st.image_topics:
        kind, table, number = "image", out.images, ""
    elif topic in st.lidar_topics:
        kind, table, number = "sweep", out.sweeps, "sweep"
    else:
        kind, table, number = "pose", out.odometry, ""
    gp = GatedPass(out, topic, ("", topic), "", table, out.tally, kind=kind, number=number,
                   checks=st.checks, spans_files=True)  # fmt: skip
    gp.handle = _handler(gp, st)
    st.passes[topic] = gp
    return gp


def _records(bag: BagFile, msg: Message, st: StreamState) -> list[Record]:
    """A message decoded as the stamped records of its topic's pass (a /tf message used as
    odometry: one per odom-base edge); an undecodable one, a record saying why."""
    try:
        obj = bag.deserialize(msg)
        if st.tf_odometry and msg.topic == st.tf_odometry[0]:
            items = [(s, T) for s, T in odom_edges(obj, *st.tf_odometry[1:])]
        else:
            items = [(stamp_ns(obj), obj)]
    except (ValueError, AttributeError) as err:
        why = RowReject(Reason.UNDECODABLE_MESSAGE, msg.file, str(err))
        return [Record(msg.ordinal, why, None, msg.file, msg.bag_time_ns)]
    return [Record(msg.ordinal, s, (msg, o), msg.file) for s, o in items]


def _handler(gp: GatedPass, st: StreamState) -> Handler:
    """The handler of a topic's messages: images, sweeps, /tf odom-base edges or poses;
    failures are RowRejects with the topic's reason."""

    def handle(_: int, stamp: int, payload: Any) -> Indexed | Held | None:
        msg, obj = payload
        try:
            if msg.topic in st.image_topics:
                return image_message(msg, obj, stamp, st.image_topics[msg.topic], st)
            if msg.topic in st.lidar_topics:
                return sweep_message(msg, obj, stamp, st, gp)
            if st.tf_odometry and msg.topic == st.tf_odometry[0]:
                return pose_row(msg, stamp, st.tf_odometry[1], obj[:3, 3],
                                rot_to_quat(obj[:3, :3]), st)  # fmt: skip
            return odometry_message(msg, obj, stamp, st)
        except RowReject:
            raise
        except (ValueError, AttributeError, KeyError) as err:
            raise RowReject(_reason(err, msg, st), msg.file, str(err)) from err

    return handle


def report_damage(bag: BagFile, out: Writers, read: bool) -> None:
    """One damage row and one reject per damaged region of `bag`.

    Reason: `unreadable_bag` when nothing could be read from it, `truncated_bag` when the file
    ends inside the region, else `damaged_region`.
    """
    size = bag.path.stat().st_size if bag.path.is_file() else 0
    for region in bag.regions:
        out.damage.append(region.row())
        for topic in region.topics:  # listed in the accounting even if none of it was read
            out.tally.read[(bag.name, topic)] += 0
        reject = region.reject()
        if not read and region.byte_start <= len(MAGIC) and region.byte_end >= size:
            reject = replace(reject, reason=Reason.UNREADABLE_BAG,
                             detail=f"{reject.detail}; no message could be read")
        elif size and region.byte_end >= size:  # the file ends inside it: cut short
            reject = replace(reject, reason=Reason.TRUNCATED_BAG)
        out.rejects.add(reject)


CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
HEADER_FIELDS = {False: ["seq", "stamp", "frame_id"], True: ["stamp", "frame_id"]}
"""std_msgs/Header fields of a ROS1 (False) and a ROS2 (True) message, in order."""


def info_key(bag: BagFile, msg: Message) -> tuple[bool, str, str, bytes]:
    """A CameraInfo's bytes without its header stamp (and ROS1 seq: the first 12 bytes after
    any CDR encapsulation header), with what decodes them (format, type, definition digest)."""
    body = msg.raw[:4] + msg.raw[12:] if bag.ros2 else msg.raw[12:]
    return bag.ros2, msg.msgtype, msg.digest, body


def _header_first(obj: Any, ros2: bool) -> bool:
    """Whether a decoded message begins with a std_msgs/Header (its stamp in bytes 0-12)."""
    names = list(getattr(obj, "__dataclass_fields__", ()))
    header = getattr(obj, "header", None)
    fields = [f for f in getattr(header, "__dataclass_fields__", ()) if f != "__msgtype__"]
    return names[:1] == ["header"] and fields == HEADER_FIELDS[ros2]


def _camera_info(bag: BagFile, msg: Message, st: StreamState) -> None:
    """Follow a camera's CameraInfo (`calib_track`); an undecodable one changes nothing.

    A CameraInfo whose bytes differ from the last one observed (and usable) only in the header
    stamp cannot change the calibration: it is not decoded again (a camera driver repeats the
    same CameraInfo with every image)."""
    camera = st.info_topics[msg.topic]
    key = info_key(bag, msg) if msg.msgtype == CAMERA_INFO else None
    if key is not None and st.info_last.get(camera) == key:
        return
    try:
        obj = bag.deserialize(msg)
    except ValueError:
        return
    stamp = stamp_ns(obj)
    track = st.tracks[camera]
    track.observe(obj, stamp, f"{msg.file}: {msg.topic}")
    same = key is not None and track.usable and _header_first(obj, bag.ros2)
    st.info_last[camera] = key if same else None


def _reason(err: Exception, msg: Message, st: StreamState) -> Reason:
    """The reject reason of a handler failure: bad pose, bad point cloud or undecodable."""
    if isinstance(err, BadPoseError):
        return Reason.BAD_POSE
    return Reason.BAD_POINTCLOUD if msg.topic in st.lidar_topics else Reason.UNDECODABLE_MESSAGE


def finish_stream(st: StreamState, out: Writers) -> None:
    """The end of the recording: release every message the checks still hold."""
    for topic in st.times.pending():  # a topic with fewer sweeps than AUTO_SWEEPS
        release_held(topic_pass(topic, st, out), st)
    for topic in sorted(st.passes):
        st.passes[topic].end_checks()
