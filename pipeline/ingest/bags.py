"""Streaming access to the bags of a mission folder: one reader per bag, damage recorded.

A mission folder holds ROS1 bags (one per sensor group, `<mission>_<suffix>.bag`) and/or ROS2
bags (folders with a `metadata.yaml`, sqlite3 or MCAP storage). Each bag is read with
`rosbags.highlevel.AnyReader`, messages of the requested topics only, one at a time. A ROS1 bag
whose index is lost (a truncated file) is read sequentially up to the damage instead
(`ros1_scan`); where reading stopped is kept in `BagFile.damage`.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1Error
from rosbags.rosbag2 import ReaderError as Ros2Error
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from pipeline.ingest.ros1_scan import Ros1Scan
from schemas.errors import DataError, MissingInputError

_READ_ERRORS = (AnyReaderError, Ros1Error, Ros2Error, SerdeError, OSError, EOFError, KeyError)


@dataclass(frozen=True)
class Message:
    """One raw message and where it lives.

    file: bag path relative to the mission folder; bag_time_ns: log time (int64 ns);
    ordinal: 0-based position among this topic's messages in this file, in reading order.
    """

    file: str
    topic: str
    msgtype: str
    bag_time_ns: int
    ordinal: int
    raw: bytes
    digest: str = ""


_COMPILED: dict[tuple[bool, str, str], Typestore] = {}
"""Typestores by (ROS2?, message type, definition digest): rosbags generates a deserializer per
type and typestore, and every reader has its own typestore, so a type met again (in the next
bag or the next recording of this process) reuses the first one's compiled code."""


def find_bags(mission_dir: Path) -> list[Path]:
    """ROS1 `.bag` files and ROS2 bag folders of a mission, sorted by name."""
    if not mission_dir.is_dir():
        raise MissingInputError(f"{mission_dir}: mission folder not found")
    if (mission_dir / "metadata.yaml").exists():
        return [mission_dir]
    bags = [p for p in mission_dir.iterdir() if p.suffix == ".bag" and p.is_file()]
    bags += [p for p in mission_dir.iterdir() if p.is_dir() and (p / "metadata.yaml").exists()]
    if not bags:
        raise MissingInputError(f"{mission_dir}: no ROS1 .bag files or ROS2 bag folders")
    return sorted(bags)


class BagFile:
    """One bag opened for streaming; `damage` says where reading stopped early, if it did."""

    def __init__(self, path: Path, mission_dir: Path) -> None:
        """Open `path` (a .bag file or a ROS2 folder) and read its topic list."""
        self.path = path
        self.name = str(path.relative_to(mission_dir)) if path != mission_dir else path.name
        self.damage: str | None = None
        self._scan: Ros1Scan | None = None
        self._reader: AnyReader | None = None
        default = get_typestore(Stores.ROS2_HUMBLE if path.suffix != ".bag" else Stores.ROS1_NOETIC)
        try:
            reader = AnyReader([path], default_typestore=default)
            reader.open()
            self._reader = reader
        except _READ_ERRORS as err:
            if path.suffix != ".bag":
                raise DataError(f"{path}: unreadable bag: {err}") from err
            self._scan = Ros1Scan(path)
            self.damage = f"index unreadable ({err}); read sequentially"

    @property
    def sequential(self) -> bool:
        """True when the bag is read by the sequential fallback (its index is damaged)."""
        return self._scan is not None

    def topics(self) -> dict[str, str] | None:
        """Topic -> message type; None when unknown before a sequential read."""
        if self._reader is None:
            return None
        return {t: info.msgtype or "" for t, info in self._reader.topics.items()}

    def messages(self, topics: Collection[str], start: int | None = None) -> Iterator[Message]:
        """Messages of `topics` in log-time order (file order when sequential), from `start` ns.

        Stops at damage instead of raising, recording it in `self.damage`.
        """
        counts: dict[str, int] = {}
        for topic, msgtype, stamp, raw, digest in self._raw(topics, start):
            ordinal = counts.get(topic, 0)
            counts[topic] = ordinal + 1
            yield Message(self.name, topic, msgtype, stamp, ordinal, raw, digest)

    def _raw(
        self, topics: Collection[str], start: int | None
    ) -> Iterator[tuple[str, str, int, bytes, str]]:
        """(topic, type, log time, raw bytes) from the indexed reader or the sequential scan."""
        if self._scan is not None:
            scan = self._scan = Ros1Scan(self.path)
            for sconn, stamp, raw in scan.messages(topics):
                if start is None or stamp >= start:
                    yield sconn.topic, sconn.msgtype, stamp, raw, ""
            if scan.damage is not None:
                self.damage = f"truncated or corrupt: {scan.damage}"
            return
        assert self._reader is not None
        conns = [c for c in self._reader.connections if c.topic in set(topics)]
        if not conns:
            return
        last = start or 0
        try:
            for conn, stamp, raw in self._reader.messages(connections=conns, start=start):
                last = stamp
                yield conn.topic, conn.msgtype, stamp, bytes(raw), conn.digest or ""
        except (*_READ_ERRORS, RuntimeError) as err:  # RuntimeError: a chunk fails to decompress
            self.damage = (f"reading stopped after log time {last} ns: "
                           f"{type(err).__name__}: {err}")

    def deserialize(self, msg: Message) -> Any:
        """Decode a raw message into its rosbags message object; ValueError naming it if bad."""
        try:
            if self._scan is not None:
                return self._scan.typestore.deserialize_ros1(msg.raw, msg.msgtype)
            reader = self._reader
            assert reader is not None
            ts = reader.typestore
            if msg.digest:
                ts = _COMPILED.setdefault((reader.is2, msg.msgtype, msg.digest), ts)
            if reader.is2:
                return ts.deserialize_cdr(msg.raw, msg.msgtype)
            return ts.deserialize_ros1(msg.raw, msg.msgtype)
        except (*_READ_ERRORS, ValueError, IndexError, TypeError) as err:
            raise DataError(
                f"{msg.file}: {msg.topic} message at log time {msg.bag_time_ns} ns "
                f"cannot be decoded as {msg.msgtype}: {err}"
            ) from err

    def close(self) -> None:
        """Release the reader."""
        if self._reader is not None:
            self._reader.close()
            self._reader = None


def stamp_ns(msg: Any) -> int:
    """Header stamp of a deserialized message as int64 nanoseconds."""
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
