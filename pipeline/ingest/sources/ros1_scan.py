"""Sequential scan of a damaged ROS1 bag: every readable chunk, damage reported and skipped.

rosbags' indexed reader needs the index at the end of the file, which a truncated or damaged bag
may have lost. This scanner walks the records from the start (like `rosbag reindex`),
decompresses each chunk and yields the messages it holds. Where a record is unreadable it
reports a `DamagedRegion` and searches forward for the next chunk header (a record header whose
fields parse and say `op=0x05`), so every undamaged chunk after the damage is still read. A cut
chunk yields what decompresses from its start. Memory: one chunk at a time.
"""

from __future__ import annotations

import bz2
import mmap
import struct
from collections.abc import Callable, Collection, Generator, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

import lz4.frame
from rosbags.rosbag1.reader import Header, ReaderError, RecordType, decompressors, normalize
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.msg import normalize_msgtype
from rosbags.typesys.store import Typestore

from pipeline.ingest.checks.damage import UNKNOWN, DamagedRegion

_U32 = struct.Struct("<L")
MAGIC = b"#ROSBAG V2.0\n"
MAX_HEADER = 1 << 16
"""A record header longer than this (bytes) is garbage (real ones are well under 1 kB)."""
MAX_RECORD = 1 << 30
"""A record longer than this (bytes) is garbage (rosbag chunks are about 768 kB)."""
END_OF_TIME = 2**63 - 1
_CHUNK_OP = b"op=\x05"


@dataclass(frozen=True)
class ScanConnection:
    """A connection record found while scanning: id, topic, normalized type, definition."""

    id: int
    topic: str
    msgtype: str
    msgdef: str


@dataclass
class _Cursor:
    """Where the scan is: the last log time seen (any topic) and a region awaiting its end."""

    last_ns: int = 0
    pending: DamagedRegion | None = None


@dataclass
class Ros1Scan:
    """Messages of a ROS1 bag read sequentially; damaged regions go to `on_damage`."""

    path: Path
    file: str = ""
    on_damage: Callable[[DamagedRegion], None] = lambda region: None
    connections: dict[int, ScanConnection] = field(default_factory=dict)
    typestore: Typestore = field(default_factory=lambda: get_typestore(Stores.EMPTY))
    chunks: dict[int, tuple[int, int]] = field(default_factory=dict)
    """Chunk record offset -> (first, last) log time of its messages, learned by a full pass."""
    _ordered: bool = False

    def topics(self) -> dict[str, str]:
        """Topic -> type of every connection record readable anywhere in the file.

        Two passes when the file is damaged: the first learns every connection (a chunk may
        hold messages whose connection record comes later), the second reports the regions.
        """
        found: list[DamagedRegion] = []
        report, self.on_damage = self.on_damage, found.append
        try:
            for _ in self.messages({"\0 no topic"}):
                pass
        finally:
            self.on_damage = report
        if found:
            for _ in self.messages({"\0 no topic"}):
                pass
        self._ordered = True
        return {c.topic: c.msgtype for c in self.connections.values()}

    def messages(self, topics: Collection[str] = (),
                 start: int | None = None) -> Iterator[tuple[ScanConnection, int, bytes]]:
        """Yield (connection, log time ns, raw bytes) for `topics` (all if empty).

        After `topics()` (a full pass), chunks are visited in the order of their first log time
        and those ending before `start` ns are skipped (a shuffled file reads in time order);
        before it, in file order.
        """
        wanted, cur = set(topics), _Cursor()
        with self.path.open("rb") as f:
            size = f.seek(0, 2)
            if size == 0:
                self._damage(cur, 0, 0, "empty file")
                self._flush(cur, END_OF_TIME)
                return
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as buf:
                if self._ordered:
                    for pos in sorted(self.chunks, key=lambda p: (self.chunks[p][0], p)):
                        if start is None or self.chunks[pos][1] >= start:
                            yield from self._step(buf, pos, wanted, cur)
                else:
                    pos = len(MAGIC)
                    if bytes(buf[:pos]) != MAGIC:
                        pos = self._resync(buf, cur, 0, "file magic is not '#ROSBAG V2.0'")
                    while pos < size:
                        pos = yield from self._step(buf, pos, wanted, cur)
        self._flush(cur, END_OF_TIME)

    def _step(self, buf: mmap.mmap, pos: int, wanted: set[str],
              cur: _Cursor) -> Generator[tuple[ScanConnection, int, bytes], None, int]:
        """Read the record at `pos`, yield its messages; return the next record's offset."""
        try:
            header, data_at, size = _record_at(buf, pos)
            op = header.get_uint8("op")
        except ReaderError as err:
            return self._resync(buf, cur, pos, f"unreadable record at byte {pos}: {err}")
        end = data_at + size
        data = bytes(buf[data_at:end])
        if op == RecordType.CHUNK:
            yield from self._chunk(header, data, pos, end, size, wanted, cur)
        elif end > len(buf):
            self._damage(cur, pos, end, f"record at byte {pos} is cut at the end of the file")
        elif op == RecordType.CONNECTION:
            try:
                self._add_connection(header, data)
            except (ReaderError, ValueError, KeyError, UnicodeDecodeError) as err:
                self._damage(cur, pos, end, f"connection record at byte {pos}: {err}")
        return end

    def _resync(self, buf: mmap.mmap, cur: _Cursor, pos: int, cause: str) -> int:
        """Report bytes from `pos` up to the next chunk header as damaged; return its offset."""
        nxt = _next_chunk(buf, pos + 1)
        self._damage(cur, pos, nxt, cause)
        return nxt

    def _damage(self, cur: _Cursor, start: int, end: int, cause: str) -> None:
        """Open a region (its last log time is the next message's, known later)."""
        self._flush(cur, cur.last_ns)
        cur.pending = DamagedRegion(self.file, start, end, (), cur.last_ns, cur.last_ns, UNKNOWN,
                                    cause)

    def _flush(self, cur: _Cursor, last_ns: int) -> None:
        """Report the pending region, ending at log time `last_ns`."""
        if cur.pending is not None:
            p, cur.pending = cur.pending, None
            self.on_damage(DamagedRegion(p.file, p.byte_start, p.byte_end, p.topics, p.first_ns,
                                         max(last_ns, p.first_ns), p.messages, p.cause))

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
            try:
                self.typestore.register(get_types_from_msg(msgdef, msgtype))
            except TypesysError as err:
                del self.connections[conn_id]
                raise ReaderError(f"connection {conn_id} ({msgtype}) has an unreadable message "
                                  f"definition: {str(err).splitlines()[0]}") from err

    def _chunk(self, header: Header, data: bytes, pos: int, end: int, size: int,
               wanted: set[str], cur: _Cursor) -> Iterator[tuple[ScanConnection, int, bytes]]:
        """Messages of one chunk; what fails to decompress or parse is a damaged region."""
        cause = None
        try:
            compression = header.get_string("compression")
            raw = decompressors[compression](data) if len(data) == size else None
            if raw is None:
                raise ReaderError(f"chunk cut at the end of the file: {len(data)} of {size} bytes")
        except (KeyError, RuntimeError, OSError, ValueError, EOFError, ReaderError) as err:
            raw = _partial(header, data)
            cause = f"chunk at byte {pos} cannot be decompressed: {err}"
        chunk, orphans, times = BytesIO(raw), [], [cur.last_ns]
        while chunk.tell() < len(raw):
            at = chunk.tell()
            try:
                inner = Header.read(chunk)
                body = _body(chunk)
                op = inner.get_uint8("op")
                if op == RecordType.CONNECTION:
                    self._add_connection(inner, body)
                    continue
                if op != RecordType.MSGDATA:
                    raise ReaderError(f"record op {op} inside a chunk")
                conn, stamp = self.connections.get(inner.get_uint32("conn")), inner.get_time("time")
            except (ReaderError, ValueError, KeyError, UnicodeDecodeError) as err:
                cause = cause or (f"chunk at byte {pos}, record at offset {at} of {len(raw)} "
                                  f"decompressed bytes: {err}")
                break
            self._flush(cur, stamp)
            cur.last_ns = max(cur.last_ns, stamp)
            times.append(stamp)
            if conn is None:
                orphans.append(stamp)
            elif not wanted or conn.topic in wanted:
                yield conn, stamp, body
        if not self._ordered:
            self.chunks[pos] = (min(times[1:] or times), max(times))
        if orphans:  # their connection record is unreadable: topic unknown
            self.on_damage(DamagedRegion(self.file, pos, end, (), min(orphans), max(orphans),
                                         len(orphans), f"chunk at byte {pos}: messages of a "
                                         "connection whose record is unreadable"))  # fmt: skip
        if cause is not None:  # after what could be recovered: the region starts there
            self._damage(cur, pos, end, cause)


def _record_at(buf: mmap.mmap, pos: int) -> tuple[Header, int, int]:
    """(header, offset of its data, declared data size) of the record at `pos`."""
    if pos + 4 > len(buf):
        raise ReaderError("file ends inside a record header length")
    hlen = _U32.unpack_from(buf, pos)[0]
    if hlen > MAX_HEADER or pos + 8 + hlen > len(buf):
        raise ReaderError(f"header length {hlen} is impossible here")
    try:
        header = Header.read(BytesIO(buf[pos : pos + 4 + hlen]))
    except (ValueError, struct.error) as err:  # a field name that is not UTF-8, ...
        raise ReaderError(f"record header does not parse: {err}") from err
    size = _U32.unpack_from(buf, pos + 4 + hlen)[0]
    if size > MAX_RECORD:
        raise ReaderError(f"record length {size} is impossible")
    return header, pos + 8 + hlen, size


def _next_chunk(buf: mmap.mmap, start: int) -> int:
    """Offset of the first parseable chunk record header at or after `start` (EOF if none)."""
    at = buf.find(_CHUNK_OP, start)
    while at >= 0:
        for pos in range(max(start, at - 256), at):
            try:
                header, _, _ = _record_at(buf, pos)
            except (ReaderError, struct.error):
                continue
            inside = pos + 4 < at < pos + 4 + _U32.unpack_from(buf, pos)[0]
            if header.get("op") == b"\x05" and inside:
                return pos
        at = buf.find(_CHUNK_OP, at + 1)
    return len(buf)


def _body(src: BytesIO) -> bytes:
    """The data of a record inside a chunk; ReaderError when it is cut."""
    raw = src.read(4)
    if len(raw) != 4:
        raise ReaderError("chunk ends inside a record length")
    size: int = _U32.unpack(raw)[0]
    body = src.read(size)
    if len(body) != size:
        raise ReaderError(f"message data has {len(body)} of {size} bytes")
    return body


def _partial(header: Header, data: bytes) -> bytes:
    """Whatever decompresses from the start of a damaged chunk (b'' when nothing does)."""
    try:
        compression = header.get_string("compression")
        if compression == "none":
            return data
        if compression == "lz4":
            return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data))
        if compression == "bz2":
            return bz2.BZ2Decompressor().decompress(data)
    except (RuntimeError, OSError, ValueError, EOFError, ReaderError):
        return b""
    return b""
