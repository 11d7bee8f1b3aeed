"""The streaming pass: each bag read once, messages of the configured topics handled one by one.

Images are gated on stamp order, decoded and rectified, handed to the image sink and indexed;
sweeps are gated, decoded for their counts and time span, and indexed; odometry is gated and
indexed. Nothing is held beyond the current message (index rows are flushed in batches).

This module reads the bags and dispatches each message to its handler: images
(`stream_images`), sweeps (`sweep_stream`), poses (`stream_poses`); the state they share is
`stream_state`.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

from packets.poses import rot_to_quat
from pipeline.ingest.checks.gate import TopicGate, Verdict
from pipeline.ingest.checks.rejects import Reject
from pipeline.ingest.core.stream_images import flush_images, image_message, release_image
from pipeline.ingest.core.stream_poses import (
    MAX_POSITION_M,
    odometry_message,
    pose_row,
    pose_verdict,
    release_pose,
)
from pipeline.ingest.core.stream_state import (
    CameraImage,
    ImageSink,
    StreamState,
    Writers,
)
from pipeline.ingest.core.sweep_stream import release_held, release_sweep, sweep_message
from pipeline.ingest.errors import BadPoseError
from pipeline.ingest.sources.bags import BagFile, Message, stamp_ns
from pipeline.ingest.sources.ros1_scan import MAGIC
from pipeline.ingest.sources.tf_odometry import odom_edges
from schemas.recording_index import Reason

__all__ = ["MAX_POSITION_M", "CameraImage", "ImageSink", "StreamState", "Writers",
           "finish_stream", "report_damage", "stream_bag"]


def stream_bag(bag: BagFile, st: StreamState, out: Writers) -> None:
    """Handle every configured message of one bag; report its damaged regions.

    Accounting: every message read is counted in `out.tally` and ends as an index row (kept)
    or a reject row (rejected); a /tf message used as odometry counts once per odom-base edge.
    """
    topics = st.wanted() & set(bag.topics())
    for msg in bag.messages(sorted(topics)):
        if msg.topic in st.info_topics:  # calibration, not data: not in the accounting
            _camera_info(bag, msg, st)
            continue
        st.seen[msg.topic] = st.seen.get(msg.topic, 0) + 1
        _handle(bag, msg, st, out)
    for topic in sorted(topics):
        gate = st.gate(topic)
        for verdict in gate.flush():
            _dispatch(verdict, gate, st, out)
        for gap in gate.gaps:
            out.rejects.add(Reject(bag.name, topic, gap.before_ns, Reason.STREAM_GAP,
                                   gap.detail()))
        gate.gaps.clear()
    flush_images(st, out)
    if st.jumps is not None:
        for pose in st.jumps.flush():
            pose_verdict(pose, st, out)
    report_damage(bag, out, read=any(f == bag.name for f, _ in out.tally.read))


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


def _handle(bag: BagFile, msg: Message, st: StreamState, out: Writers) -> None:
    """Decode one message and pass it through its topic's gate."""
    try:
        obj = bag.deserialize(msg)
        if st.tf_odometry and msg.topic == st.tf_odometry[0]:
            items = [(s, (msg, T)) for s, T in odom_edges(obj, *st.tf_odometry[1:])]
        else:
            items = [(stamp_ns(obj), (msg, obj))]
    except (ValueError, AttributeError) as err:
        out.tally.read[(msg.file, msg.topic)] += 1
        out.rejects.add(Reject(msg.file, msg.topic, msg.bag_time_ns, Reason.UNDECODABLE_MESSAGE,
                               str(err)))  # fmt: skip
        return
    out.tally.read[(msg.file, msg.topic)] += len(items)
    gate = st.gate(msg.topic)
    for stamp, item in items:
        for verdict in gate.push(stamp, item):
            _dispatch(verdict, gate, st, out)


def _dispatch(verdict: Verdict, gate: TopicGate, st: StreamState, out: Writers) -> None:
    """Reject a refused message, else hand it to its topic's handler; failures are rejects."""
    msg, obj = verdict.item
    stamp = verdict.stamp_ns
    if verdict.reason is not None:
        out.rejects.add(Reject(msg.file, msg.topic, stamp, verdict.reason, verdict.detail))
        return
    ok: bool | None
    try:
        if msg.topic in st.image_topics:
            ok = image_message(msg, obj, stamp, st.image_topics[msg.topic], st, out)
        elif msg.topic in st.lidar_topics:
            ok = sweep_message(msg, obj, stamp, st, out)
        elif st.tf_odometry and msg.topic == st.tf_odometry[0]:
            T = obj
            ok = pose_row(msg, stamp, st.tf_odometry[1], T[:3, 3], rot_to_quat(T[:3, :3]), st,
                           out)  # fmt: skip
        else:
            ok = odometry_message(msg, obj, stamp, st, out)
    except (ValueError, AttributeError, KeyError) as err:
        out.rejects.add(Reject(msg.file, msg.topic, stamp, _reason(err, msg, st), str(err)))
        return
    if ok is None:  # a pose, kept or rejected once its neighbours are read
        gate.accepted(stamp)
    elif ok:
        out.tally.kept[(msg.file, msg.topic)] += 1
        gate.accepted(stamp)


def _reason(err: Exception, msg: Message, st: StreamState) -> Reason:
    """The reject reason of a handler failure: bad pose, bad point cloud or undecodable."""
    if isinstance(err, BadPoseError):
        return Reason.BAD_POSE
    return Reason.BAD_POINTCLOUD if msg.topic in st.lidar_topics else Reason.UNDECODABLE_MESSAGE


def finish_stream(st: StreamState, out: Writers) -> None:
    """The end of the recording: release every message the checks still hold."""
    for topic in st.times.pending():  # a topic with fewer sweeps than AUTO_SWEEPS
        release_held(topic, st, out)
    for topic in sorted(st.fits):
        gate = st.fits[topic]
        for rel in gate.flush():
            if topic in st.lidar_topics:
                release_sweep(rel, out)
            elif topic in st.image_topics:
                release_image(rel, st, out)
            else:
                release_pose(rel, out)
