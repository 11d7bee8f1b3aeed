"""Streaming access to the bags of a mission folder: one reader per bag, damage recorded.

A mission folder holds ROS1 bags (one per sensor group, `<mission>_<suffix>.bag`), ROS2 bags
(folders with a `metadata.yaml`, sqlite3 or MCAP storage) and/or loose MCAP files (`.mcap`,
profile `ros1` as `mcap convert` writes a bag, or `ros2`). Each bag is read with
`rosbags.highlevel.AnyReader`, an MCAP file with `pipeline.ingest.sources.mcap_bag` (also a rosbag2
folder whose one MCAP file is not in profile `ros2`), messages of the requested topics only, one
at a time; `BagFile` gives the same interface whatever the format. A ROS1 bag
whose index is lost (a truncated file) is read sequentially instead (`ros1_scan`); a damaged
chunk is skipped (`ros1_index`, `ros1_scan`) and the unreadable byte ranges are kept in
`BagFile.regions`.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Ros1Error
from rosbags.rosbag2 import ReaderError as Ros2Error
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from pipeline.ingest.checks.damage import UNKNOWN, DamagedRegion
from pipeline.ingest.sources.mcap_bag import McapBag, is_mcap, mcap_profile
from pipeline.ingest.sources.ros1_index import IndexedRos1
from pipeline.ingest.sources.ros1_scan import END_OF_TIME, Ros1Scan
from schemas.errors import DataError, MissingInputError

_READ_ERRORS = (AnyReaderError, Ros1Error, Ros2Error, SerdeError, OSError, EOFError, KeyError)
_OPEN_ERRORS = (*_READ_ERRORS, AssertionError, ValueError, IndexError, OverflowError,
                struct.error, UnicodeDecodeError)
"""What rosbags raises opening a bag whose index is garbage (it asserts on some of it)."""


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
    verified: bool = False
    """Its bytes are checksummed: it came from an LZ4 chunk whose content checksum was
    verified on decompression (as `rosbag record --lz4` writes them)."""


_COMPILED: dict[tuple[bool, str, str], Typestore] = {}
"""Typestores by (ROS2?, message type, definition digest): rosbags generates a deserializer per
type and typestore, and every reader has its own typestore, so a type met again (in the next
bag or the next recording of this process) reuses the first one's compiled code."""


def split_order(path: Path) -> tuple[object, ...]:
    """Sort key of a bag path: its name with the numbers in it compared as numbers, so the
    parts of a split recording (`x_2.bag` before `x_10.bag`) are read in time order."""
    parts = re.split(r"(\d+)", path.name)
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in parts)


def bag_path(mission_dir: Path, file: str) -> Path:
    """The path of the bag an index row names (`Message.file`): the mission folder itself when
    it is a rosbag2 folder named so (`BagFile.name` of such a bag), else a path inside it."""
    if file == mission_dir.name and (mission_dir / "metadata.yaml").exists() and not (
            mission_dir / file).exists():  # fmt: skip
        return mission_dir
    return mission_dir / file


BAG_SUFFIXES = (".bag", ".mcap")
"""Files read as bags: ROS1 bags and loose MCAP files."""


def find_bags(mission_dir: Path) -> list[Path]:
    """ROS1 `.bag` files, loose `.mcap` files and ROS2 bag folders of a mission, in
    `split_order`; a mission folder that is itself a rosbag2 folder (`metadata.yaml` inside, any
    number of storage files) is the one bag. MissingInputError naming what was skipped and why
    when there is none."""
    if not mission_dir.is_dir():
        raise MissingInputError(f"{mission_dir}: mission folder not found")
    if (mission_dir / "metadata.yaml").exists():
        return rosbag2_parts(mission_dir)
    bags = [p for p in mission_dir.iterdir() if p.suffix in BAG_SUFFIXES and p.is_file()]
    bags += [q for p in sorted(mission_dir.iterdir()) if p.is_dir()
             and (p / "metadata.yaml").exists() for q in rosbag2_parts(p)]  # fmt: skip
    if not bags:
        skipped = [f"{p.name} ({why})" for p in sorted(mission_dir.iterdir(), key=split_order)
                   if (why := skipped_because(p)) is not None]  # fmt: skip
        listed = "; ".join(skipped[:SKIPPED_LISTED]) + (
            f"; and {len(skipped) - SKIPPED_LISTED} more" if len(skipped) > SKIPPED_LISTED
            else "")  # fmt: skip
        raise MissingInputError(f"{mission_dir}: no ROS1 .bag files, .mcap files or ROS2 bag "
                                f"folders" + (f" (skipped: {listed})" if skipped else " (empty)"))
    return sorted(bags, key=split_order)


def rosbag2_parts(folder: Path) -> list[Path]:
    """A rosbag2 folder as the bags to open: the folder (rosbags reads it; a lone MCAP file in
    it is read by `BagFile` as that file), or its MCAP files one by one, in `split_order`, when
    there are several and all are of profile ros1 (`mcap convert` of the parts of a split ROS1
    bag wrapped in a rosbag2 folder; rosbag2 reads profile ros2 only)."""
    mcaps = sorted(folder.glob("*.mcap"), key=split_order)
    others = [p for p in folder.iterdir() if p.is_file() and p.suffix != ".mcap"
              and p.name != "metadata.yaml" and not p.name.startswith(".")]  # fmt: skip
    if len(mcaps) > 1 and not others and all(mcap_profile(p) == "ros1" for p in mcaps):
        return mcaps
    return [folder]


SKIPPED_LISTED = 5
"""Files named in the error of a folder holding no bag (the rest are counted)."""


def skipped_because(path: Path) -> str | None:
    """Why `find_bags` does not read `path` as a bag (None: a hidden file, not worth naming)."""
    if path.name.startswith("."):
        return None
    if path.is_dir():
        return "a folder without metadata.yaml: not a ROS2 bag"
    if path.suffix == ".db3":
        return "ROS2 sqlite3 storage without the metadata.yaml of its bag folder"
    if is_mcap(path):
        return "MCAP content without the .mcap suffix"
    return "not a .bag, .mcap or ROS2 bag folder"


class BagFile:
    """One bag opened for streaming; `regions` lists the byte ranges that could not be read."""

    def __init__(self, path: Path, mission_dir: Path) -> None:
        """Open `path` (a .bag file or a ROS2 folder) and read its topic list."""
        self.path = path
        self.name = str(path.relative_to(mission_dir)) if path != mission_dir else path.name
        self._regions: dict[tuple[int, int], DamagedRegion] = {}
        self.index_error: str | None = None
        self._scan: Ros1Scan | None = None
        self._reader: AnyReader | None = None
        self._mcap: McapBag | None = None
        self._topics: dict[str, str] | None = None
        if path.suffix == ".mcap" and path.is_file():
            self._mcap = McapBag(path, self.name)
            return
        default = get_typestore(Stores.ROS2_HUMBLE if path.suffix != ".bag" else Stores.ROS1_NOETIC)
        try:
            reader = AnyReader([path], default_typestore=default)
            reader.open()
            self._reader = reader
        except _OPEN_ERRORS as err:
            if path.suffix != ".bag":
                lone = _lone_mcap(path)
                if lone is not None:  # e.g. profile ros1, which rosbag2 does not read
                    self._mcap = McapBag(lone, self.name)
                    return
                profiles = {mcap_profile(p) for p in path.glob("*.mcap")} - {None, "ros2"}
                if profiles:
                    raise DataError(
                        f"{path}: unsupported rosbag2 folder: MCAP storage in profile "
                        f"{', '.join(map(repr, sorted(map(str, profiles))))} (rosbag2 reads "
                        "'ros2'; m3gd reads .mcap files of profile ros1 or ros2 as loose files, "
                        "without the metadata.yaml)") from err  # fmt: skip
                raise DataError(f"{path}: unreadable bag: {err}") from err
            self._scan = Ros1Scan(path, self.name)
            self.index_error = f"{type(err).__name__}: {err}".splitlines()[0]

    @property
    def kind(self) -> str:
        """The format: rosbag1, rosbag2, mcap-ros1 or mcap-ros2."""
        if self._mcap is not None:
            return f"mcap-{self._mcap.profile}"
        return "rosbag1" if self.path.suffix == ".bag" else "rosbag2"

    @property
    def mcap(self) -> McapBag | None:
        """The MCAP reader of a bag read as an MCAP file (None for a rosbag)."""
        return self._mcap

    @property
    def ros2(self) -> bool:
        """True for a ROS2 bag (CDR messages), False for ROS1."""
        if self._mcap is not None:
            return self._mcap.is2
        return self._reader is not None and bool(self._reader.is2)

    @property
    def sequential(self) -> bool:
        """True when the bag is read by the sequential fallback (its index is damaged)."""
        return self._scan is not None

    @property
    def regions(self) -> list[DamagedRegion]:
        """Byte ranges found unreadable by any read of this bag so far, in file order."""
        return [self._regions[k] for k in sorted(self._regions)]

    def add_region(self, region: DamagedRegion) -> None:
        """Record a damaged region, merged with an earlier one of the same byte range."""
        key = (region.byte_start, region.byte_end)
        old = self._regions.get(key)
        if old is not None:
            region = replace(
                old, topics=tuple(sorted({*old.topics, *region.topics})),
                first_ns=min(old.first_ns, region.first_ns),
                last_ns=max(old.last_ns, region.last_ns),
                messages=_merged_count(old, region))  # fmt: skip
        self._regions[key] = region

    @property
    def damage(self) -> str | None:
        """What is damaged, in one line (None for an intact bag)."""
        parts = [f"index unreadable ({self.index_error}); read sequentially"] if (
            self.index_error) else []
        parts += [r.describe() for r in self.regions[:3]]
        if len(self.regions) > 3:
            parts.append(f"and {len(self.regions) - 3} more damaged region(s)")
        return "; ".join(parts) or None

    def topics(self) -> dict[str, str]:
        """Topic -> message type (of a damaged bag: the connection records a scan can read)."""
        if self._topics is None:
            if self._scan is not None:
                self._scan = Ros1Scan(self.path, self.name, self.add_region)
                self._topics = self._scan.topics()
            elif self._mcap is not None:
                self._topics = self._mcap.topics()
            else:
                assert self._reader is not None
                self._topics = {t: i.msgtype or "" for t, i in self._reader.topics.items()}
        return self._topics

    def messages(self, topics: Collection[str], start: int | None = None) -> Iterator[Message]:
        """Messages of `topics` in log-time order (file order when sequential), from `start` ns.

        Damaged chunks are skipped and recorded in `self.regions`.
        """
        counts: dict[str, int] = {}
        for topic, msgtype, stamp, raw, digest, verified in self._raw(topics, start):
            ordinal = counts.get(topic, 0)
            counts[topic] = ordinal + 1
            yield Message(self.name, topic, msgtype, stamp, ordinal, raw, digest, verified)

    def _raw(
        self, topics: Collection[str], start: int | None
    ) -> Iterator[tuple[str, str, int, bytes, str, bool]]:
        """(topic, type, log time, raw bytes, digest, checksum verified) from the index or the
        sequential scan."""
        if self._scan is not None:
            if not topics:
                return
            self.topics()  # the survey: connection records from anywhere in the file
            scan = self._scan
            assert scan is not None
            for sconn, stamp, raw in scan.messages(topics, start):
                if start is None or stamp >= start:
                    yield sconn.topic, sconn.msgtype, stamp, raw, "", False
            return
        if self._mcap is not None:
            yield from self._mcap.messages(topics, start, self.add_region)
            return
        assert self._reader is not None
        conns = [c for c in self._reader.connections if c.topic in set(topics)]
        if not conns:
            return
        if self._reader.is2:
            yield from self._ros2(conns, start)
            return
        ros1 = IndexedRos1(self._reader.readers[0], self.name, self.add_region)
        for conn, stamp, raw in ros1.messages(conns, start):
            yield conn.topic, conn.msgtype, stamp, bytes(raw), conn.digest or "", ros1.verified

    def _ros2(self, conns: list[Any], start: int | None) -> Iterator[tuple[str, str, int, bytes,
                                                                       str, bool]]:
        """Messages of a ROS2 bag; a read error ends it with a region of unknown extent."""
        assert self._reader is not None
        last = start or 0
        try:
            for conn, stamp, raw in self._reader.messages(connections=conns, start=start):
                last = stamp
                yield conn.topic, conn.msgtype, stamp, bytes(raw), conn.digest or "", False
        except (*_READ_ERRORS, RuntimeError) as err:
            self.add_region(DamagedRegion(
                self.name, 0, 0, tuple(sorted({c.topic for c in conns})), last, END_OF_TIME,
                UNKNOWN, f"reading stopped: {type(err).__name__}: {err}"))  # fmt: skip

    def deserialize(self, msg: Message) -> Any:
        """Decode a raw message into its rosbags message object; ValueError naming it if bad."""
        try:
            if self._scan is not None:
                return self._scan.typestore.deserialize_ros1(msg.raw, msg.msgtype)
            ts = self._typestore()
            if msg.digest:
                ts = _COMPILED.setdefault((self.ros2, msg.msgtype, msg.digest), ts)
            if self.ros2:
                return ts.deserialize_cdr(msg.raw, msg.msgtype)
            return ts.deserialize_ros1(msg.raw, msg.msgtype)
        except (*_READ_ERRORS, ValueError, IndexError, TypeError) as err:
            raise DataError(
                f"{msg.file}: {msg.topic} message at log time {msg.bag_time_ns} ns "
                f"cannot be decoded as {msg.msgtype}: {err}"
            ) from err

    def _typestore(self) -> Typestore:
        """The typestore of the bag's own message definitions."""
        if self._mcap is not None:
            return self._mcap.typestore
        assert self._reader is not None
        return self._reader.typestore

    def close(self) -> None:
        """Release the reader."""
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        if self._mcap is not None:
            self._mcap.close()


def _lone_mcap(folder: Path) -> Path | None:
    """The one MCAP file of a rosbag2 folder that holds no other storage file (None else)."""
    if not folder.is_dir():
        return None
    files = [p for p in folder.iterdir() if p.is_file() and p.name != "metadata.yaml"]
    return files[0] if len(files) == 1 and is_mcap(files[0]) else None


def _merged_count(a: DamagedRegion, b: DamagedRegion) -> int:
    """Messages of one byte range reported twice: by other topics (a read of other topics)
    they add up, by the same topics (a read again) they do not; UNKNOWN stays unknown."""
    if UNKNOWN in (a.messages, b.messages):
        return UNKNOWN
    return a.messages + b.messages if a.topics != b.topics else max(a.messages, b.messages)


def stamp_ns(msg: Any) -> int:
    """Header stamp of a deserialized message as int64 nanoseconds."""
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
