"""`inspect_recording`: the whole inspection of a ROS1 / ROS2 recording or an HF mission."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

from packets.poses import invert_T, make_T, quat_to_rot
from pipeline.ingest.sources.bags import BagFile, stamp_ns
from pipeline.ingest.sources.registry import source_for
from pipeline.ingest.sources.tf_odometry import POSE_TYPES, pose_of
from pipeline.inspect import sample
from pipeline.inspect.cameras import IMAGE_TYPES, INFO_TYPE, camera_report, pair_info
from pipeline.inspect.clouds import CLOUD_TYPE, cloud_report
from pipeline.inspect.decide import agreement_of, decide_rig
from pipeline.inspect.model import Agreement, Inspection, TopicStats
from pipeline.inspect.rates import timing
from pipeline.inspect.scan import TopicTimes, file_sizes, open_bags, recording_times
from pipeline.inspect.tf import Key, Series, tf_sample
from schemas.errors import DataError, MissingInputError


def inspect_recording(path: Path) -> Inspection:
    """Inspect a `.bag` or `.mcap` file, a ROS2 bag folder, a mission folder of bags or an HF
    mission.

    MissingInputError (naming `path`) when there is nothing to read; DataError for a bag that
    cannot be opened.
    """
    began = time.perf_counter()
    if not path.exists():
        raise MissingInputError(f"{path}: no such file or folder")
    return source_for(path).inspect(path, began)


def inspect_bags(path: Path, began: float) -> Inspection:
    """Inspect a `.bag` or `.mcap` file, a ROS2 bag folder or a mission folder of bags
    (`RosbagSource.inspect`); `began`: `time.perf_counter()` at the start."""
    mission, bags = open_bags(path)
    try:
        bad = {b.name: why for b in bags if b.path.is_file() and (why := not_a_bag(b.path))}
        if bad and len(bad) == len(bags):
            raise DataError("; ".join(f"{name}: {why}" for name, why in bad.items()))
        ins = _inspect_bags(path, mission, bags, began)
        return replace(ins, notes=(*ins.notes, *(f"{n}: {w}" for n, w in bad.items())))
    finally:
        for bag in bags:
            bag.close()


MAGIC = {".bag": b"#ROSBAG V2.0\n", ".mcap": b"\x89MCAP0\r\n"}
"""The first bytes of a ROS1 bag and of an MCAP file."""


def not_a_bag(path: Path) -> str | None:
    """Why the file `path` is not a bag of its suffix (empty, or not starting with its format's
    magic bytes), or None when it starts as one."""
    magic = MAGIC.get(path.suffix)
    if magic is None:
        return None
    size = path.stat().st_size
    if size == 0:
        return "an empty file (0 bytes), not a bag"
    with path.open("rb") as f:
        head = f.read(len(magic))
    if head != magic:
        kind = "ROS1 bag" if path.suffix == ".bag" else "MCAP file"
        return (f"not a {kind}: it does not start with {magic!r} ({size} bytes, starting "
                f"{head[:8]!r})")
    return None


def topic_stats(topic: str, tt: TopicTimes, files: tuple[str, ...]) -> TopicStats:
    """A topic's row from its index times."""
    if tt.times is None:
        return TopicStats(topic, tt.msgtype, tt.count, files=files)
    t = timing(tt.times)
    return TopicStats(topic, tt.msgtype, tt.count, t.first_ns, t.last_ns, t.rate_hz, t.period_s,
                      t.n_gaps, t.gaps, files)  # fmt: skip


def _inspect_bags(path: Path, mission: Path, bags: list[BagFile], began: float) -> Inspection:
    """The inspection of opened bags."""
    times = recording_times(bags)
    topics = tuple(topic_stats(t, tt, files) for t, (tt, files) in sorted(times.items()))
    types = {t.topic: t.msgtype for t in topics}
    tf, _, series = tf_sample(bags, types)
    clouds = tuple(cloud_report(bags, t) for t, m in types.items() if m == CLOUD_TYPE)
    infos = [t for t, m in types.items() if m == INFO_TYPE]
    cameras = tuple(
        camera_report(bags, t, m, (info := pair_info(t, infos)),
                      times[info][0].times if info is not None else None)
        for t, m in types.items() if m in IMAGE_TYPES)  # fmt: skip
    notes = [f"{b.name}: {b.damage}" for b in bags if b.damage]
    notes += [f"{t.topic}: the index gives no message times (no rate or gaps)"
              for t in topics if t.first_ns is None and t.count]  # fmt: skip
    kinds = {b.kind for b in bags}
    odo = odometry(bags, types)
    agree = tuple(a for o in odo if (a := _agreement(bags, o, types[o[0]], series)) is not None)
    decisions = decide_rig(tf, odo, types, clouds, cameras, {t.topic: t.count for t in topics},
                           {t.topic: t.rate_hz for t in topics}, agree)  # fmt: skip
    return Inspection(str(path), "+".join(sorted(kinds)), file_sizes(mission, bags), topics, tf,
                      clouds, cameras, odo, tuple(notes), time.perf_counter() - began, agree,
                      decisions)  # fmt: skip


ODOMETRY_SAMPLE = 200
"""Odometry messages read to compare a topic with /tf."""


def _agreement(bags: list[BagFile], odo: tuple[str, str, str], msgtype: str,
               series: dict[Key, Series]) -> Agreement | None:  # fmt: skip
    """An odometry topic against the sampled /tf edge between its two frames (either
    direction), or None when /tf has no such edge or the topic cannot be read."""
    topic, frame, child = odo
    for (parent, kid, static, tf_topic), got in series.items():
        if static or {parent, kid} != {frame, child}:
            continue
        tf_T = got.T if parent == frame else [invert_T(T) for T in got.T]
        stamps, poses = [], []
        try:
            for _, msg in sample.first(bags, topic, ODOMETRY_SAMPLE):
                pose, _ = pose_of(msgtype, msg)
                q, p = pose.orientation, pose.position
                stamps.append(stamp_ns(msg))
                poses.append(make_T(quat_to_rot([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z]))
        except (DataError, ValueError):
            return None
        return agreement_of(topic, f"{tf_topic} {parent}->{kid}", (got.stamps, tf_T),
                            (stamps, poses))  # fmt: skip
    return None


def odometry(bags: list[BagFile], types: dict[str, str]) -> tuple[tuple[str, str, str], ...]:
    """(topic, frame_id, child_frame_id) of the first message of every odometry topic
    (`tf_odometry.POSE_TYPES`; child '' for a pose type without one), nav_msgs/Odometry
    first."""
    out = []
    for topic in sorted((t for t, m in types.items() if m in POSE_TYPES),
                        key=lambda t: (POSE_TYPES.index(types[t]), t)):  # fmt: skip
        try:
            got = next(sample.first(bags, topic, 1), None)
        except DataError:
            got = None
        if got is not None:
            msg = got[1]
            out.append((topic, str(msg.header.frame_id).lstrip("/"),
                        str(getattr(msg, "child_frame_id", "")).lstrip("/")))  # fmt: skip
    return tuple(out)
