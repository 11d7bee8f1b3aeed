"""Indexed reading of a ROS1 bag that survives damaged chunks.

rosbags' `Reader.messages` stops at the first chunk that fails to decompress or parse, losing
every later chunk. This walks the same chunk index (log-time order across chunks) but handles a
damaged chunk by recording it as a `DamagedRegion` (its byte range, and from the index the
topics, log times and count of the messages it held) and going on with the next chunk. A message
whose record inside an otherwise readable chunk is garbage is recorded the same way.
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Callable, Collection, Iterator
from io import BytesIO
from typing import Any

from rosbags.rosbag1.reader import Header, ReaderError, RecordType, read_uint32

from pipeline.ingest.checks.damage import DamagedRegion

_CHUNK_ERRORS = (ReaderError, RuntimeError, OSError, ValueError, EOFError, KeyError,
                 AssertionError, IndexError)  # fmt: skip
"""What a garbage chunk or record raises while being decompressed or parsed."""

Raw = tuple[Any, int, bytes]  # (rosbags Connection, log time ns, raw message bytes)
LZ4_MAGIC = b"\x04\x22\x4d\x18"
CONTENT_CHECKSUM = 0x04
"""Flag of an LZ4 frame descriptor (its fifth byte): the frame carries an XXH32 checksum of its
content, which lz4.frame verifies while decompressing (a mismatch raises: a damaged region)."""


def checksummed(data: bytes) -> bool:
    """True when compressed chunk `data` is an LZ4 frame with a content checksum (roslz4)."""
    return len(data) > 4 and data[:4] == LZ4_MAGIC and bool(data[4] & CONTENT_CHECKSUM)


class IndexedRos1:
    """Messages of selected connections of an open rosbags ROS1 `Reader`, damage skipped."""

    def __init__(self, reader: Any, file: str, on_damage: Callable[[DamagedRegion], None]) -> None:
        """`reader`: an open `rosbags.rosbag1.Reader`; `file`: its name for the damage rows."""
        self.reader = reader
        self.file = file
        self.on_damage = on_damage
        self._chunk: tuple[int, BytesIO | None] = (-1, None)
        self._bad: set[int] = set()
        self.verified = False
        """Whether the chunk of the last message yielded had its content checksum verified."""

    def messages(self, connections: Collection[Any], start: int | None = None) -> Iterator[Raw]:
        """(connection, log time, raw) in log-time order from `start` ns, damage skipped."""
        conns = {c.id: c for c in connections}
        tagged = [_tag(self.reader.indexes[cid], cid) for cid in conns]
        for entry, cid in heapq.merge(*tagged, key=lambda pair: pair[0]):
            if start is not None and entry.time < start:
                continue
            if entry.chunk_pos in self._bad:
                continue
            chunk = self._load(entry.chunk_pos, conns, start)
            if chunk is None:
                continue
            raw = self._record(chunk, entry, conns[cid])
            if raw is not None:
                yield raw

    def _load(self, pos: int, conns: dict[int, Any], start: int | None) -> BytesIO | None:
        """The decompressed chunk at `pos` (cached); None and a region when it is damaged."""
        if self._chunk[0] == pos:
            return self._chunk[1]
        head = self.reader.chunks[pos]
        try:
            self.reader.bio.seek(head.datapos)
            data = self.reader.bio.read(head.datasize)
            if len(data) != head.datasize:
                raise ReaderError(f"chunk data cut: {len(data)} of {head.datasize} bytes")
            chunk: BytesIO | None = BytesIO(head.decompressor(data))
            self.verified = checksummed(data)
        except _CHUNK_ERRORS as err:
            self._bad.add(pos)
            self._region(pos, head.datapos + head.datasize, conns, start, _cause(err))
            chunk = None
        self._chunk = (pos, chunk)
        return chunk

    def _record(self, chunk: BytesIO, entry: Any, conn: Any) -> Raw | None:
        """The message record at `entry.offset`; None and a one-message region if garbage."""
        try:
            chunk.seek(entry.offset)
            while True:
                header = Header.read(chunk)
                op = header.get_uint8("op")
                if op != RecordType.CONNECTION:
                    break
                chunk.seek(read_uint32(chunk), os.SEEK_CUR)
            if op != RecordType.MSGDATA:
                raise ReaderError(f"record op {op} where message data was indexed")
            size = read_uint32(chunk)
            data = chunk.read(size)
            if len(data) != size:
                raise ReaderError(f"message data has {len(data)} of {size} bytes")
            conn_id, stamp = header.get_uint32("conn"), header.get_time("time")
            if conn_id != conn.id:
                raise ReaderError(f"record names connection {conn_id}, the index {conn.id}")
        except _CHUNK_ERRORS as err:
            head = self.reader.chunks[entry.chunk_pos]
            info = next(c for c in self.reader.chunk_infos if c.pos == entry.chunk_pos)
            first, last = min(info.start_time, entry.time), max(info.end_time, entry.time)
            self.on_damage(DamagedRegion(
                self.file, head.datapos, head.datapos + head.datasize, (conn.topic,), first,
                last, 1, f"message record at offset {entry.offset} of the chunk at byte "
                f"{entry.chunk_pos}: {_cause(err)}"))  # fmt: skip
            return None
        return conn, stamp, data  # the record's log time (an index entry may be the damaged one)

    def _region(self, pos: int, end: int, conns: dict[int, Any], start: int | None,
                cause: str) -> None:
        """Report the chunk at `pos` as damaged with what the index says it held."""
        info = next(c for c in self.reader.chunk_infos if c.pos == pos)
        if not any(i in conns for i in info.connection_counts):
            return  # the chunk holds none of the requested messages: nothing lost
        # every topic the chunk index says it holds, requested or not (a camera dropped for
        # its lost camera_info still lost its images here)
        known = {c.id: c.topic for c in self.reader.connections}
        held = [i for i in info.connection_counts if i in known]
        times = [e.time for i in held for e in self.reader.indexes.get(i, [])
                 if e.chunk_pos == pos and (start is None or e.time >= start)]  # fmt: skip
        if not times:
            return
        topics = tuple(sorted({known[i] for i in held}))
        self.on_damage(DamagedRegion(self.file, pos, end, topics, min(times), max(times),
                                     len(times), f"chunk at byte {pos}: {cause}"))


def _tag(entries: list[Any], cid: int) -> Iterator[tuple[Any, int]]:
    """(index entry, connection id) for each entry of one connection's index."""
    for entry in entries:
        yield entry, cid


def _cause(err: BaseException) -> str:
    """`Type: message` of an exception, on one line."""
    return f"{type(err).__name__}: {err}".splitlines()[0]
