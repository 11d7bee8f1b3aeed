"""The streaming pass: each bag read once, messages of the configured topics handled one by one.

Images are gated on stamp order, decoded and rectified, handed to the image sink and indexed;
sweeps are gated, decoded for their counts and time span, and indexed; odometry is gated and
indexed. Nothing is held beyond the current message (index rows are flushed in batches).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

from packets.poses import rot_to_quat
from pipeline.ingest.bags import BagFile, Message, stamp_ns
from pipeline.ingest.check_fit import Release
from pipeline.ingest.errors import BadPoseError
from pipeline.ingest.gate import TopicGate, Verdict
from pipeline.ingest.pointcloud import (
    MAX_COORD_M,
    MAX_TIME_S,
    cloud_view,
    kept_points,
    sweep_counts,
    view_summary,
)
from pipeline.ingest.rejects import Reject
from pipeline.ingest.ros1_scan import MAGIC
from pipeline.ingest.stream_images import flush_images, image_message, release_image
from pipeline.ingest.stream_poses import (
    MAX_POSITION_M,
    odometry_message,
    pose_row,
    pose_verdict,
    release_pose,
)
from pipeline.ingest.stream_state import (
    CameraImage,
    ImageSink,
    StreamState,
    Writers,
    where_columns,
)
from pipeline.ingest.sweep_checks import SWEEP_CHECKS, sweep_problems
from pipeline.ingest.tf_odometry import odom_edges
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
            span, step = (gap.after_ns - gap.before_ns) / 1e9, gap.median_step_ns / 1e9
            detail = f"silent {span:.3f} s until {gap.after_ns} ns (median step {step:.3f} s)"
            out.rejects.add(Reject(bag.name, topic, gap.before_ns, Reason.STREAM_GAP, detail))
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


def _camera_info(bag: BagFile, msg: Message, st: StreamState) -> None:
    """Follow a camera's CameraInfo (`calib_track`); an undecodable one changes nothing."""
    try:
        obj = bag.deserialize(msg)
    except ValueError:
        return
    stamp = stamp_ns(obj)
    st.tracks[st.info_topics[msg.topic]].observe(obj, stamp, f"{msg.file}: {msg.topic}")


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
        elif msg.topic == st.lidar_topic:
            ok = _sweep(msg, obj, stamp, st, out)
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
    return Reason.BAD_POINTCLOUD if msg.topic == st.lidar_topic else Reason.UNDECODABLE_MESSAGE


def finish_stream(st: StreamState, out: Writers) -> None:
    """The end of the recording: release every message the checks still hold."""
    for topic in sorted(st.fits):
        gate = st.fits[topic]
        for rel in gate.flush():
            if topic == st.lidar_topic:
                _release_sweep(rel, out)
            elif topic in st.image_topics:
                release_image(rel, st, out)
            else:
                release_pose(rel, out)


def _sweep(msg: Message, obj: Any, stamp: int, st: StreamState, out: Writers) -> bool | None:
    """Index one PointCloud2 with its counts and time span; False when rejected, None when its
    topic's checks hold it (decided later, `_release_sweep`).

    The message's contract decides what is damage (`pointcloud.point_kinds`): invalid returns
    (NaN/Inf in any coordinate) and zero points are dropped and counted by kind, the sweep kept.
    A cloud that says it is dense yet holds invalid returns contradicts itself: the same, with
    one warning per topic. A sweep without a valid point is rejected (`empty_sweep`); one with
    a corrupt point (beyond MAX_COORD_M, or a broken time) is damaged (`nonfinite_points`); one
    its topic's plausibility checks find impossible is damaged too (`bad_pointcloud`).
    """
    view = cloud_view(obj)  # decoded once for the summary and the checks
    c, t_first, t_last = view_summary(view, stamp)
    if c.valid == 0:
        detail = (f"no valid points: {c.total} in message ({c.kinds()}, {c.corrupt} "
                  "corrupt)")  # fmt: skip
        out.rejects.add(Reject(msg.file, msg.topic, stamp, Reason.EMPTY_SWEEP, detail))
        return False
    if c.corrupt:
        detail = (f"{c.corrupt} of {c.total} points corrupt (a coordinate beyond "
                  f"{MAX_COORD_M:g} m, or a point time that is not finite or beyond "
                  f"{MAX_TIME_S:g} s): a damaged message")  # fmt: skip
        out.rejects.add(Reject(msg.file, msg.topic, stamp, Reason.NONFINITE_POINTS, detail))
        return False
    if c.nonfinite and bool(getattr(obj, "is_dense", False)) and msg.topic not in st.dense_warned:
        st.dense_warned.add(msg.topic)
        st.notes.append(f"{msg.file}: {msg.topic}: the cloud at stamp {stamp} ns says is_dense "
                        f"but holds {c.nonfinite} invalid returns ({c.kinds()}): they are "
                        "dropped and counted, its sweeps kept (told once per topic)")
    row = {"stamp_ns": stamp, **where_columns(msg), **sweep_counts(c), "t_first_ns": t_first,
           "t_last_ns": t_last}  # fmt: skip
    if not st.checks.enabled:
        _release_sweep(Release((msg, row)), out, count=False)
        return True
    gate = st.fit(msg.topic, SWEEP_CHECKS)
    trusted = st.trusted(msg)
    problems = {} if trusted else sweep_problems(kept_points(view, stamp), st.checks,
                                                 gate.active)  # fmt: skip
    for rel in gate.push((msg, row), problems, trusted):
        _release_sweep(rel, out)
    return None


def _release_sweep(rel: Release, out: Writers, count: bool = True) -> None:
    """Index a sweep let go by its topic's checks (counted kept when `count`), or reject it."""
    msg, row = rel.item
    if rel.rejected_by is not None:
        check, problem = rel.rejected_by
        out.rejects.add(Reject(msg.file, msg.topic, row["stamp_ns"], Reason.BAD_POINTCLOUD,
                               f"{problem} ({check}): a damaged message"))  # fmt: skip
        return
    out.sweeps.append({"sweep": out.sweeps.count, **row})
    if count:
        out.tally.kept[(msg.file, msg.topic)] += 1
