"""The streaming pass: each bag read once, messages of the configured topics handled one by one.

Images are gated on stamp order, decoded and rectified, handed to the image sink and indexed;
sweeps are gated, decoded for their counts and time span, and indexed; odometry is gated and
indexed. Nothing is held beyond the current message (index rows are flushed in batches).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import simplejpeg

from packets.poses import F64, compose, make_T, quat_to_rot, rot_to_quat
from pipeline.ingest.bags import BagFile, Message, stamp_ns
from pipeline.ingest.calib_track import CalibrationTrack
from pipeline.ingest.camera import CorruptImageError, Rectifier
from pipeline.ingest.check_fit import FitGate, Release
from pipeline.ingest.errors import BadPoseError, CalibrationMismatchError, UnsupportedImageError
from pipeline.ingest.gate import TopicGate, Verdict
from pipeline.ingest.image_checks import Cells, cell_means, cell_size, drift_problem
from pipeline.ingest.image_decode import image_kind
from pipeline.ingest.pointcloud import (
    MAX_COORD_M,
    MAX_TIME_S,
    cloud_view,
    kept_points,
    sweep_counts,
    view_summary,
)
from pipeline.ingest.pose_checks import JumpFilter, PoseVerdict, quat_norm_problem
from pipeline.ingest.rejects import Reject, RejectLog, Tally
from pipeline.ingest.ros1_scan import MAGIC
from pipeline.ingest.sweep_checks import SWEEP_CHECKS, sweep_problems
from pipeline.ingest.tf_odometry import odom_edges
from pipeline.ingest.tf_tree import TfTree
from schemas.config import ChecksConfig
from schemas.recording_index import IndexTableWriter, Reason


class CameraImage(NamedTuple):
    """One rectified output image, in stamp order per camera.

    frame: 0-based index among the camera's accepted images; stamp_ns: header stamp (int64 ns);
    image: (out_h, out_w, 3) uint8 RGB; K_out: (3, 3) float64 intrinsics of `image`.
    """

    camera: str
    frame: int
    stamp_ns: int
    image: npt.NDArray[np.uint8]
    K_out: F64


ImageSink = Callable[[CameraImage], None]


@dataclass
class Writers:
    """The streamed index tables and the reject log."""

    images: IndexTableWriter
    sweeps: IndexTableWriter
    odometry: IndexTableWriter
    rejects: RejectLog
    damage: IndexTableWriter

    @property
    def tally(self) -> Tally:
        """Messages read, kept and rejected per (bag file, topic)."""
        return self.rejects.tally


@dataclass
class StreamState:
    """Per-topic stamp gates and per-camera frame counters across bags."""

    rectifiers: dict[str, Rectifier]
    image_topics: dict[str, str]
    lidar_topic: str
    odom_topic: str
    tf: TfTree
    base_frame: str
    sink: ImageSink | None
    tf_odometry: tuple[str, str, str] | None = None  # (/tf topic, odom frame, base frame)
    checks: ChecksConfig = field(default_factory=ChecksConfig)
    gates: dict[str, TopicGate] = field(default_factory=dict)
    jumps: JumpFilter | None = None
    held: dict[str, HeldImage] = field(default_factory=dict)
    last_ok: dict[str, Cells] = field(default_factory=dict)
    frames: dict[str, int] = field(default_factory=dict)
    seen: dict[str, int] = field(default_factory=dict)
    fits: dict[str, FitGate] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    dense_warned: set[str] = field(default_factory=set)
    tracks: dict[str, CalibrationTrack] = field(default_factory=dict)
    info_topics: dict[str, str] = field(default_factory=dict)  # CameraInfo topic -> camera
    unsupported: set[str] = field(default_factory=set)

    def fit(self, topic: str, checks: tuple[str, ...]) -> FitGate:
        """The plausibility checks of `topic` (`check_fit`)."""
        if topic not in self.fits:
            self.fits[topic] = FitGate(topic, checks, self.checks.calibration_messages,
                                       self.checks.max_reject_share)  # fmt: skip
        return self.fits[topic]

    def trusted(self, msg: Message) -> bool:
        """True when a verified checksum vouches for the message's bytes and the config
        trusts it: its per-message checks are skipped (they look for flipped bytes)."""
        return msg.verified and self.checks.trust_checksums

    def check_rows(self) -> list[dict[str, object]]:
        """Checks-table rows: every check on every topic it ran on."""
        return [row for topic in sorted(self.fits) for row in self.fits[topic].rows()]

    def warnings(self) -> list[str]:
        """What the stream told the user: self-contradicting clouds, checks that do not fit."""
        return (self.notes + [n for c in sorted(self.tracks) for n in self.tracks[c].notes]
                + [n for topic in sorted(self.fits) for n in self.fits[topic].notes])

    def jump_filter(self) -> JumpFilter | None:
        """The odometry jump filter (None when the checks are off)."""
        if self.jumps is None and self.checks.enabled:
            self.jumps = JumpFilter(self.checks.max_speed_m_s)
        return self.jumps

    def gate(self, topic: str) -> TopicGate:
        """The stamp gate of `topic`."""
        return self.gates.setdefault(topic, TopicGate())

    def wanted(self) -> set[str]:
        """Topics to stream: images of cameras that can be rectified, LiDAR, odometry."""
        images = {t for t, c in self.image_topics.items() if c in self.rectifiers}
        infos = {t for t, c in self.info_topics.items() if c in self.tracks}
        tf = {self.tf_odometry[0]} if self.tf_odometry else set()
        return images | infos | {self.lidar_topic, self.odom_topic} | tf

    def rectifier_at(self, camera: str, stamp: int) -> Rectifier | str | None:
        """The camera's rectifier at `stamp` (its CameraInfo then), why there is none usable
        (a string), or None when the camera has no CameraInfo at all."""
        track = self.tracks.get(camera)
        return track.at(stamp) if track is not None else self.rectifiers.get(camera)


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
    _flush_images(st, out)
    if st.jumps is not None:
        for pose in st.jumps.flush():
            _pose_verdict(pose, st, out)
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
            ok = _image(msg, obj, stamp, st.image_topics[msg.topic], st, out)
        elif msg.topic == st.lidar_topic:
            ok = _sweep(msg, obj, stamp, st, out)
        elif st.tf_odometry and msg.topic == st.tf_odometry[0]:
            T = obj
            ok = _pose_row(msg, stamp, st.tf_odometry[1], T[:3, 3], rot_to_quat(T[:3, :3]), st,
                           out)  # fmt: skip
        else:
            ok = _odometry(msg, obj, stamp, st, out)
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


def _where(msg: Message) -> dict[str, object]:
    """The location columns of an index row."""
    return {"file": msg.file, "topic": msg.topic, "bag_time_ns": msg.bag_time_ns,
            "ordinal": msg.ordinal}  # fmt: skip


@dataclass(frozen=True)
class HeldImage:
    """A decoded, rectified image waiting for its next frame to be judged (`image_checks`):
    its message, stamp (ns), output image, JPEG size and cells."""

    msg: Message
    stamp_ns: int
    image: npt.NDArray[np.uint8]
    jpeg_bytes: int
    cells: Cells | None
    K_out: F64


def _image(msg: Message, obj: Any, stamp: int, camera: str, st: StreamState,
           out: Writers) -> bool | None:  # fmt: skip
    """Rectify one CompressedImage, hand it to the sink and index it; False if rejected.

    With the image checks on it is held (None: decided later) until the camera's next image
    is decoded, then judged against it and the last accepted image (`_judge_image`).
    """
    rect = st.rectifier_at(camera, stamp)
    if rect is None:  # no camera_info: reported once by read_static
        return False
    where = f"{msg.file}: {msg.topic} at stamp {stamp} ns"
    data = np.asarray(obj.data, dtype=np.uint8)
    try:
        kind = image_kind(msg.msgtype, obj, msg.topic)
        if isinstance(rect, str):
            raise CalibrationMismatchError(f"{where}: its CameraInfo is unusable: {rect}")
        decoded = rect.decode_message(kind, obj, where)
    except UnsupportedImageError as err:
        _unsupported(msg, stamp, str(err), st, out)
        return False
    except (CorruptImageError, CalibrationMismatchError) as err:
        reason = Reason.CORRUPT_JPEG if isinstance(err, CorruptImageError) else (
            Reason.CALIBRATION_MISMATCH)  # fmt: skip
        out.rejects.add(Reject(msg.file, msg.topic, stamp, reason, str(err)))
        return False
    image = rect.remap(decoded)
    c = st.checks
    if not (c.enabled and (c.image_step_z or c.image_blip_levels)):
        _emit_image(msg, stamp, camera, image, int(data.size), rect.K_out, st, out)
        return True
    if st.trusted(msg) or kind != "jpeg":  # no drift check (it looks for JPEG DC damage):
        prev = st.held.pop(camera, None)  # handed on in order, after any image still held
        if prev is not None:
            _judge_image(prev, None, st, out)
        for rel in st.fit(msg.topic, IMAGE_CHECKS).push(
                HeldImage(msg, stamp, image, int(data.size), None, rect.K_out), {},
                trusted=True):  # fmt: skip
            _release_image(rel, st, out)
        return None
    sub = simplejpeg.decode_jpeg_header(data.tobytes())[3]
    cells = Cells(stamp, cell_means(decoded, cell_size(sub, rect.reduction)))
    prev = st.held.pop(camera, None)
    if prev is not None:
        _judge_image(prev, cells, st, out)
    st.held[camera] = HeldImage(msg, stamp, image, int(data.size), cells, rect.K_out)
    return None


def _unsupported(msg: Message, stamp: int, detail: str, st: StreamState, out: Writers) -> None:
    """Refuse an image of an encoding m3gd does not read: a reject row per message (counted
    as `unsupported_image`, not damage) and one warning per topic."""
    if msg.topic not in st.unsupported:
        st.unsupported.add(msg.topic)
        st.notes.append(f"{msg.file}: {detail}; its images are not ingested (counted as "
                        "unsupported_image, not as damage)")  # fmt: skip
    out.rejects.add(Reject(msg.file, msg.topic, stamp, Reason.UNSUPPORTED_IMAGE, detail))


def _judge_image(held: HeldImage, after: Cells | None, st: StreamState, out: Writers) -> None:
    """Emit a held image, or reject it when it disagrees with its neighbouring frames.

    Its neighbours: the camera's last accepted image and the next decoded one (`after`, not
    judged yet). It is judged against both, or against the last accepted one alone; never
    against an unjudged image alone (a damaged next frame would cost a good image).
    """
    c, msg = st.checks, held.msg
    camera = st.image_topics[msg.topic]
    before = st.last_ok.get(camera)
    near = [n for n in (before, after) if n is not None] if before is not None else []
    gate = st.fit(msg.topic, IMAGE_CHECKS)
    problem = None
    assert held.cells is not None  # only unverified images are held for their next frame
    if gate.active("image_drift"):
        problem = drift_problem(held.cells, near, c.image_step_z or np.inf,
                                c.image_blip_levels or np.inf, c.image_max_gap_s)  # fmt: skip
    if problem is None:
        st.last_ok[camera] = held.cells
    for rel in gate.push(held, {"image_drift": problem}):
        _release_image(rel, st, out)


IMAGE_CHECKS = ("image_drift",)
POSE_CHECKS = ("quat_norm", "pose_jump")


def _release_image(rel: Release, st: StreamState, out: Writers) -> None:
    """Emit an image let go by its topic's checks, or reject it."""
    held: HeldImage = rel.item
    msg = held.msg
    if rel.rejected_by is not None:
        out.rejects.add(Reject(msg.file, msg.topic, held.stamp_ns, Reason.CORRUPT_JPEG,
                               rel.rejected_by[1]))  # fmt: skip
        return
    camera = st.image_topics[msg.topic]
    _emit_image(msg, held.stamp_ns, camera, held.image, held.jpeg_bytes, held.K_out, st, out)
    out.tally.kept[(msg.file, msg.topic)] += 1


def finish_stream(st: StreamState, out: Writers) -> None:
    """The end of the recording: release every message the checks still hold."""
    for topic in sorted(st.fits):
        gate = st.fits[topic]
        for rel in gate.flush():
            if topic == st.lidar_topic:
                _release_sweep(rel, out)
            elif topic in st.image_topics:
                _release_image(rel, st, out)
            else:
                _release_pose(rel, out)


def _flush_images(st: StreamState, out: Writers) -> None:
    """Judge every held image against the last accepted one (the end of a bag)."""
    for camera in sorted(st.held):
        _judge_image(st.held.pop(camera), None, st, out)


def _emit_image(msg: Message, stamp: int, camera: str, image: npt.NDArray[np.uint8],
                jpeg_bytes: int, K_out: F64, st: StreamState, out: Writers) -> None:  # fmt: skip
    """Number an accepted image, hand it to the sink (with the intrinsics `K_out` of its own
    calibration) and index it."""
    frame = st.frames.get(camera, 0)
    st.frames[camera] = frame + 1
    if st.sink is not None:
        st.sink(CameraImage(camera, frame, stamp, image, K_out))
    row = {"camera": camera, "frame": frame, "stamp_ns": stamp, **_where(msg),
           "jpeg_bytes": jpeg_bytes}  # fmt: skip
    out.images.append(row)


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
    row = {"stamp_ns": stamp, **_where(msg), **sweep_counts(c), "t_first_ns": t_first,
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


MAX_POSITION_M = 1e6
"""An odometry position farther than this (m) from its origin is corrupt (a robot's mission
spans kilometres); such poses are rejected, not interpolated into camera poses."""


def _odometry(msg: Message, obj: Any, stamp: int, st: StreamState, out: Writers) -> bool | None:
    """Index one nav_msgs/Odometry pose as T_odom_base (re-based if the child is another frame).

    BadPoseError for a non-finite, zero, absurdly far or (checks on) non-unit quaternion pose.
    """
    p, q = obj.pose.pose.position, obj.pose.pose.orientation
    pos = np.array([p.x, p.y, p.z], dtype=np.float64)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    with np.errstate(over="ignore"):  # a flipped exponent: inf, refused as not unit below
        tiny = float(np.linalg.norm(quat)) < 1e-9
    if not (np.isfinite(pos).all() and np.isfinite(quat).all()) or tiny:
        raise BadPoseError(f"non-finite or zero pose: position {pos.tolist()}, "
                           f"quat {quat.tolist()}")
    if np.abs(pos).max() > MAX_POSITION_M:
        raise BadPoseError(f"position {pos.tolist()} m is beyond {MAX_POSITION_M:g} m of the "
                         "odometry origin: a corrupt pose")
    problem = quat_norm_problem(quat, st.checks.quat_norm_tol) if st.checks.enabled else None
    quat = quat / np.linalg.norm(quat)
    child = str(obj.child_frame_id).lstrip("/") or st.base_frame
    if child != st.base_frame:
        T = compose(make_T(quat_to_rot(quat), pos), st.tf.lookup(child, st.base_frame))
        pos, quat = T[:3, 3], rot_to_quat(T[:3, :3])
    return _pose_row(msg, stamp, str(obj.header.frame_id).lstrip("/"), pos, quat, st, out,
                     problem)


def _pose_row(msg: Message, stamp: int, frame: str, pos: F64, quat: F64, st: StreamState,
              out: Writers, quat_problem: str | None = None) -> bool | None:  # fmt: skip
    """Append one T_odom_base pose (position m, quaternion x, y, z, w) to the odometry table.

    With the checks on, the pose first passes the jump filter, then its topic's checks (the
    quaternion norm verdict `quat_problem` and the jump verdict): None (decided later, when its
    neighbours are read; `_release_pose` keeps or rejects it and counts it).
    """
    row = {"stamp_ns": stamp, "frame_id": frame, "child_frame_id": st.base_frame,
           "position": pos.tolist(), "quat_xyzw": quat.tolist()}  # fmt: skip
    jumps = st.jump_filter()
    if jumps is None:
        out.odometry.append(row)
        return True
    for verdict in jumps.push(stamp, pos, (msg, row, quat_problem)):
        _pose_verdict(verdict, st, out)
    return None


def _pose_verdict(verdict: PoseVerdict, st: StreamState, out: Writers) -> None:
    """Hand a pose judged by the jump filter to its topic's checks."""
    msg, row, quat_problem = verdict.item
    gate = st.fit(msg.topic, POSE_CHECKS)
    problems = {"quat_norm": quat_problem, "pose_jump": verdict.problem}
    for rel in gate.push((msg, row), problems, st.trusted(msg)):
        _release_pose(rel, out)


def _release_pose(rel: Release, out: Writers) -> None:
    """Keep (index and count) or reject a pose let go by its topic's checks."""
    msg, row = rel.item
    if rel.rejected_by is None:
        out.odometry.append(row)
        out.tally.kept[(msg.file, msg.topic)] += 1
        return
    out.rejects.add(Reject(msg.file, msg.topic, row["stamp_ns"], Reason.BAD_POSE,
                           rel.rejected_by[1]))  # fmt: skip
