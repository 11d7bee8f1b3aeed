"""Topics, message types, counts and log times of a recording's bags, from their indexes.

No message is decompressed: a ROS1 bag's connection index (one entry per message: log time,
chunk), a ROS2 MCAP file's message index records (log time and offset per message, listed in
its summary's chunk indexes; a loose MCAP file's likewise), a ROS2 sqlite3 file's `timestamp`
column. Bags are opened through `pipeline.ingest.sources.bags.BagFile` (the
reader ingest uses); a ROS1
bag whose index is damaged gives its topics and no times.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from pipeline.ingest.sources.bags import BAG_SUFFIXES, BagFile, find_bags
from schemas.errors import MissingInputError

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
