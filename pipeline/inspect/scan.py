"""Topics, message types, counts and log times of a recording's bags, from their indexes.

No message is decompressed: a ROS1 bag's connection index (one entry per message: log time,
chunk), a ROS2 MCAP file's message index records (log time and offset per message, listed in
its summary's chunk indexes; a loose MCAP file's likewise), a ROS2 sqlite3 file's `timestamp`
column. Bags are opened through `pipeline.ingest.sources.bags.BagFile` (the
reader ingest uses); a ROS1
bag whose index is damaged gives its topics and no times. `inspect_bags`: the bag family's
inspection (`RosbagSource.inspect`).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from packets.poses import invert_T, make_T, quat_to_rot
from pipeline.ingest.sources.bags import BAG_SUFFIXES, BagFile, find_bags, stamp_ns
from pipeline.ingest.sources.tf_odometry import POSE_TYPES, pose_of
from pipeline.inspect import sample
from pipeline.inspect.cameras import IMAGE_TYPES, INFO_TYPE, camera_report, pair_info
from pipeline.inspect.clouds import CLOUD_TYPE, cloud_report
from pipeline.inspect.decide import agreement_of, decide_rig
from pipeline.inspect.model import Agreement, Inspection, TopicStats
from pipeline.inspect.rates import timing
from pipeline.inspect.tf import Key, Series, tf_sample
from schemas.errors import DataError, MissingInputError

I64 = npt.NDArray[np.int64]
_MSG_INDEX_OP = 0x07
_HEAD = struct.Struct("<BQHI")  # op, record length, channel id, byte length of the entries


@dataclass
class TopicTimes:
    """One topic in one bag: its type, message count and log times (None: not indexed)."""

    msgtype: str
    count: int
    times: I64 | None


def open_bags(path: Path) -> tuple[Path, list[BagFile]]:
    """(mission folder, opened bags) of a `.bag` or `.mcap` file, a ROS2 bag folder or a
    mission folder; MissingInputError naming `path` when it holds none."""
    if path.is_file():
        if path.suffix not in BAG_SUFFIXES:
            raise MissingInputError(f"{path}: not a ROS1 .bag file, an .mcap file, a ROS2 bag "
                                    "folder or a mission folder")  # fmt: skip
        return path.parent, [BagFile(path, path.parent)]
    bags = find_bags(path)
    return path, [BagFile(b, path) for b in bags]


def _anyreader(bag: BagFile) -> Any:
    """The open `rosbags.highlevel.AnyReader` of a bag (None when read sequentially)."""
    return getattr(bag, "_reader", None)


def bag_times(bag: BagFile) -> dict[str, TopicTimes]:
    """Topic -> type, count and log times of one bag, from its index."""
    if bag.mcap is not None:
        return {t: TopicTimes(m, n, times) for t, (m, n, times) in bag.mcap.times().items()}
    reader = _anyreader(bag)
    if reader is None:  # damaged ROS1 index: topics from the connection records only
        return {t: TopicTimes(m, 0, None) for t, m in bag.topics().items()}
    if not reader.is2:
        ros1 = reader.readers[0]
        out: dict[str, list[I64]] = {}
        types: dict[str, str] = {}
        for conn in ros1.connections:
            entries = ros1.indexes.get(conn.id, [])
            out.setdefault(conn.topic, []).append(
                np.fromiter((e.time for e in entries), np.int64, len(entries)))
            types[conn.topic] = conn.msgtype
        return {t: _merge(types[t], parts) for t, parts in out.items()}
    return _ros2_times(reader.readers[0])


def _merge(msgtype: str, parts: list[I64]) -> TopicTimes:
    """One topic's times from several connections or files, sorted."""
    times = np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
    return TopicTimes(msgtype, int(times.size), times)


def _ros2_times(reader2: Any) -> dict[str, TopicTimes]:
    """Times of every topic of a rosbag2 reader (its storage files one by one)."""
    storage = reader2.storage
    storages = getattr(storage, "storages", [storage])
    types = {c.topic: c.msgtype for c in reader2.connections}
    counts = {c.topic: int(c.msgcount) for c in reader2.connections}
    parts: dict[str, list[I64]] = {}
    complete = True
    for st in storages:
        found = _storage_times(st)
        if found is None:
            complete = False
            continue
        for topic, times in found.items():
            parts.setdefault(topic, []).append(times)
    if not complete:
        return {t: TopicTimes(m, counts.get(t, 0), None) for t, m in types.items()}
    return {t: _merge(m, parts.get(t, [])) for t, m in types.items()}


def _storage_times(storage: Any) -> dict[str, I64] | None:
    """Topic -> log times of one MCAP or sqlite3 file; None when it has no message index."""
    if hasattr(storage, "dbconn"):
        rows = storage.dbconn.execute(
            "SELECT topics.name, messages.timestamp FROM messages JOIN topics "
            "ON messages.topic_id = topics.id")  # fmt: skip
        out: dict[str, list[int]] = {}
        for name, stamp in rows:
            out.setdefault(str(name), []).append(int(stamp))
        return {t: np.asarray(v, np.int64) for t, v in out.items()}
    chunks = getattr(storage, "chunks", None)
    if not chunks:
        return None
    topics = {cid: ch.topic for cid, ch in storage.channels.items()}
    found: dict[str, list[I64]] = {}
    with Path(storage.path).open("rb") as f:
        for cid, times in _mcap_index(f, chunks):
            found.setdefault(topics.get(cid, f"<channel {cid}>"), []).append(times)
    return {t: np.concatenate(v) for t, v in found.items()}


def _mcap_index(f: Any, chunks: list[Any]) -> Iterator[tuple[int, I64]]:
    """(channel id, log times) of every message index record of every chunk."""
    for chunk in chunks:
        for cid, offset in chunk.message_index_offsets.items():
            f.seek(offset)
            head = f.read(_HEAD.size)
            if len(head) < _HEAD.size:
                continue
            op, _, channel, size = _HEAD.unpack(head)
            if op != _MSG_INDEX_OP or channel != cid:
                continue
            entries = np.frombuffer(f.read(size), dtype="<u8").reshape(-1, 2)
            yield cid, entries[:, 0].astype(np.int64)


def recording_times(bags: list[BagFile]) -> dict[str, tuple[TopicTimes, tuple[str, ...]]]:
    """Topic -> its times over every bag (merged, sorted) and the bags holding it."""
    per: dict[str, list[tuple[str, TopicTimes]]] = {}
    for bag in bags:
        for topic, tt in bag_times(bag).items():
            per.setdefault(topic, []).append((bag.name, tt))
    out = {}
    for topic, items in per.items():
        files = tuple(name for name, _ in items)
        known = [tt.times for _, tt in items if tt.times is not None]
        if len(known) == len(items):
            merged = _merge(items[0][1].msgtype, [k for k in known if k is not None])
        else:
            merged = TopicTimes(items[0][1].msgtype, sum(tt.count for _, tt in items), None)
        out[topic] = (merged, files)
    return out


def file_sizes(mission_dir: Path, bags: list[BagFile]) -> dict[str, int]:
    """Bytes of every bag (a ROS2 bag: its folder's files)."""
    sizes = {}
    for bag in bags:
        p = bag.path
        sizes[bag.name] = (sum(f.stat().st_size for f in p.iterdir() if f.is_file())
                           if p.is_dir() else p.stat().st_size)  # fmt: skip
    return sizes


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
