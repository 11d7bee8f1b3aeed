"""Sequential scan of a damaged ROS1 bag: read chunk by chunk up to the damage.

rosbags' indexed reader needs the index at the end of the file, which a truncated bag has lost.
This scanner walks the records from the start (like `rosbag reindex`), decompresses each chunk,
and yields the messages it holds; it stops at the first record it cannot read and says where.
Memory: one chunk at a time.
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

import lz4.frame
from rosbags.rosbag1.reader import Header, ReaderError, RecordType, decompressors, normalize
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.msg import normalize_msgtype
from rosbags.typesys.store import Typestore

_U32 = struct.Struct("<L")


@dataclass(frozen=True)
class ScanConnection:
    """A connection record found while scanning: id, topic, normalized type, definition."""

    id: int
    topic: str
    msgtype: str
    msgdef: str


@dataclass
class Ros1Scan:
    """Messages of a ROS1 bag read sequentially; `damage` says where reading stopped, if it did."""

    path: Path
    connections: dict[int, ScanConnection] = field(default_factory=dict)
    damage: str | None = None
    typestore: Typestore = field(default_factory=lambda: get_typestore(Stores.EMPTY))

    def messages(self, topics: Collection[str] = ()) -> Iterator[tuple[ScanConnection, int, bytes]]:
        """Yield (connection, log time ns, raw bytes) in file order for `topics` (all if empty)."""
        wanted = set(topics)
        with self.path.open("rb") as bio:
            if not bio.readline().startswith(b"#ROSBAG V2.0"):
                self.damage = "file magic is not '#ROSBAG V2.0'"
                return
            for op, header, data, pos in self._records(bio):
                if op == RecordType.CONNECTION:
                    self._add_connection(header, data)
                elif op == RecordType.CHUNK:
                    yield from self._chunk(header, data, pos, wanted)
                if self.damage is not None:
                    return

    def _records(self, bio: BinaryIO) -> Iterator[tuple[int, Header, bytes, int]]:
        """Top-level records (op, header, data, file offset) until EOF or damage."""
        while True:
            pos = bio.tell()
            head = bio.read(4)
            if not head:
                return
            try:
                if len(head) != 4:
                    raise ReaderError("file ends inside a record header length")
                body = bio.read(_U32.unpack(head)[0])
                header = Header.read(BytesIO(head + body))
                op = header.get_uint8("op")
                size = _read_u32(bio)
                data = bio.read(size)
                if len(data) != size:
                    cut = f"record at byte {pos} is cut: {len(data)} of {size} bytes"
                    if op == RecordType.CHUNK:  # recover the messages before the cut
                        yield op, header, data, pos
                    self.damage = self.damage or cut
                    return
            except ReaderError as err:
                self.damage = f"unreadable record at byte {pos}: {err}"
                return
            yield op, header, data, pos

    def _add_connection(self, header: Header, data: bytes) -> None:
        """Register a connection record (its header names the topic, its data the type)."""
        conn_id = header.get_uint32("conn")
        if conn_id in self.connections:
            return
        inner = Header.read(BytesIO(_U32.pack(len(data)) + data))
        msgtype = normalize_msgtype(inner.get_string("type"))
        msgdef = inner.get_string("message_definition")
        self.connections[conn_id] = ScanConnection(
            conn_id, normalize(header.get_string("topic")), msgtype, msgdef
        )
        if msgtype not in self.typestore.fielddefs:
            self.typestore.register(get_types_from_msg(msgdef, msgtype))

    def _chunk(
        self, header: Header, data: bytes, pos: int, wanted: set[str]
    ) -> Iterator[tuple[ScanConnection, int, bytes]]:
        """Messages of one chunk; a chunk that fails to decompress or parse is damage."""
        compression = header.get_string("compression")
        try:
            raw = decompressors[compression](data)
        except (KeyError, RuntimeError, OSError, ValueError) as err:
            raw = _partial(compression, data)
            self.damage = f"chunk at byte {pos} ({compression}) cannot be decompressed: {err}"
        chunk = BytesIO(raw)
        while chunk.tell() < len(raw):
            try:
                inner = Header.read(chunk)
                size = _read_u32(chunk)
                body = chunk.read(size)
                if len(body) != size:
                    raise ReaderError(f"message data has {len(body)} of {size} bytes")
                op = inner.get_uint8("op")
            except ReaderError as err:
                self.damage = self.damage or f"chunk at byte {pos} is cut or corrupt: {err}"
                return
            if op == RecordType.CONNECTION:
                self._add_connection(inner, body)
            elif op == RecordType.MSGDATA:
                conn = self.connections.get(inner.get_uint32("conn"))
                if conn is not None and (not wanted or conn.topic in wanted):
                    yield conn, inner.get_time("time"), body


def _read_u32(src: BinaryIO) -> int:
    """Read a little-endian uint32; ReaderError when the file ends."""
    raw = src.read(4)
    if len(raw) != 4:
        raise ReaderError("file ends inside a record length")
    value: int = _U32.unpack(raw)[0]
    return value


def _partial(compression: str, data: bytes) -> bytes:
    """Whatever decompresses from the start of a cut chunk (b'' when nothing does)."""
    try:
        if compression == "none":
            return data
        if compression == "lz4":
            return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data))
        if compression == "bz2":
            return bz2.BZ2Decompressor().decompress(data)
    except (RuntimeError, OSError, ValueError, EOFError):
        return b""
    return b""
