"""A loose MCAP file read like a bag: topics, raw messages in log-time order, decoding.

Robotics users share recordings as one `.mcap` per bag (`mcap convert x.bag x.mcap`: profile
`ros1`, schemas `ros1msg`, messages `ros1`) or as ROS 2 MCAP (profile `ros2`, schemas `ros2msg`
or `ros2idl`, messages `cdr`). The file's summary (chunk indexes, channels, schemas) is read
with the official `mcap` reader; each chunk's message index gives (log time, offset) per
message, so messages of the requested topics are read chunk by chunk in log-time order across
chunks, the order `rosbags` gives a ROS1 bag (ties: channel order). The raw bytes are the ROS1 or
CDR serialization a bag holds; they are decoded by a `rosbags` typestore built from the file's
own schemas, so decoded messages are the objects a bag gives.

A chunk that does not decompress or fails its CRC is a `DamagedRegion` (its byte range, and from
the message index the topics, log times and count it held); the next chunk is read. A profile,
message encoding, schema encoding or chunk compression m3gd does not read is *unsupported* (a
`DataError` naming the file and what is not read), never reported as damage.
"""

from __future__ import annotations

import heapq
import struct
import zlib
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import IO, Any

import lz4.frame
import numpy as np
import numpy.typing as npt
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex
from mcap.summary import Summary
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.msg import normalize_msgtype
from rosbags.typesys.store import Typestore

from pipeline.ingest.checks.damage import UNKNOWN, DamagedRegion
from pipeline.ingest.sources.ros1_scan import END_OF_TIME
from schemas.errors import DataError

I64 = npt.NDArray[np.int64]
Raw = tuple[str, str, int, bytes, str, bool]
"""(topic, message type, log time ns, raw bytes, definition digest, chunk CRC verified)."""

MAGIC = b"\x89MCAP0\r\n"
ENCODINGS: dict[str, tuple[str, tuple[str, ...]]] = {
    "ros1": ("ros1", ("ros1msg",)),
    "ros2": ("cdr", ("ros2msg", "ros2idl")),
}
"""Profile -> the message encoding and the schema encodings of its channels that m3gd reads."""
COMPRESSIONS = ("", "zstd", "lz4")
_OP_MESSAGE = 0x05
_OP_MESSAGE_INDEX = 0x07
_RECORD = struct.Struct("<BQ")  # opcode, record length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_INDEX_HEAD = struct.Struct("<BQHI")  # op, record length, channel id, entries' byte length
_SEP = "=" * 80 + "\n"
_OPEN_ERRORS = (McapError, OSError, EOFError, ValueError, KeyError, IndexError, struct.error,
                UnicodeDecodeError, AssertionError)  # fmt: skip
"""What the `mcap` reader raises on a file whose header or summary is garbage."""
_CHUNK_ERRORS = (McapError, OSError, EOFError, ValueError, KeyError, IndexError, struct.error,
                 RuntimeError, zstandard.ZstdError)  # fmt: skip


def is_mcap(path: Path) -> bool:
    """True when `path` is a file that begins with the MCAP magic."""
    try:
        with path.open("rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def mcap_profile(path: Path) -> str | None:
    """The profile in an MCAP file's header record (None: not an MCAP file, or unreadable)."""
    try:
        with path.open("rb") as f:
            return str(make_reader(f).get_header().profile)
    except _OPEN_ERRORS:
        return None


Entry = tuple[int, int, int]
"""One message of the index: (log time, chunk number, offset in the chunk's records)."""


class McapBag:
    """One MCAP file of profile `ros1` or `ros2`, opened for streaming like a bag."""

    def __init__(self, path: Path, name: str) -> None:
        """Open `path` and read its summary; DataError naming the file when it is unreadable
        (no summary, garbage) or unsupported (profile, encodings, compression)."""
        self.path = path
        self.name = name
        self._f: IO[bytes] | None = path.open("rb")
        try:
            reader = make_reader(self._f)
            profile = str(reader.get_header().profile)
            summary = reader.get_summary()
        except _OPEN_ERRORS as err:
            self.close()
            raise DataError(f"{path}: unreadable MCAP file: {_cause(err)}") from err
        if summary is None:
            self.close()
            raise DataError(f"{path}: MCAP file without a summary section (cut short, or written "
                            "without one: `mcap recover` rebuilds it)")  # fmt: skip
        try:
            self._check(profile, summary)
        except DataError:
            self.close()
            raise
        self.profile = profile
        self.is2 = profile == "ros2"
        self._summary = summary
        self._chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        self._channels = {cid: summary.channels[cid] for cid in sorted(summary.channels)}
        self.typestore, self._types = self._typestore(summary)
        self._digests = {cid: self._digest(cid) for cid in self._channels}
        self._indexed = bool(self._chunks) and all(c.message_index_offsets for c in self._chunks)
        self._index: dict[int, list[Entry]] | None = None
        self._lost: dict[int, str] = {}  # chunk number -> why its message index is unreadable
        self._cached: tuple[int, bytes | None, bool] = (-1, None, False)
        self._bad: set[int] = set()

    def _check(self, profile: str, summary: Summary) -> None:
        """DataError (unsupported) for a profile, an encoding or a compression not read."""
        if profile not in ENCODINGS:
            raise DataError(f"{self.path}: unsupported MCAP profile {profile!r} (m3gd reads "
                            f"profiles {', '.join(ENCODINGS)})")  # fmt: skip
        encoding, schemas = ENCODINGS[profile]
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            if channel.message_encoding != encoding or schema is None or (
                    schema.encoding not in schemas):  # fmt: skip
                got = "no schema" if schema is None else f"schema encoding {schema.encoding!r}"
                raise DataError(
                    f"{self.path}: unsupported MCAP channel {channel.topic} (message encoding "
                    f"{channel.message_encoding!r}, {got}; profile {profile} needs "
                    f"{encoding!r} with {' or '.join(schemas)})")  # fmt: skip
        for chunk in summary.chunk_indexes:
            if chunk.compression not in COMPRESSIONS:
                raise DataError(f"{self.path}: unsupported MCAP chunk compression "
                                f"{chunk.compression!r} (m3gd reads zstd, lz4 and none)")

    def _typestore(self, summary: Summary) -> tuple[Typestore, dict[int, str]]:
        """A typestore holding the file's schemas, and channel id -> message type (ROS 2
        style names, as rosbags names ROS1 types)."""
        types: dict[str, Any] = {}
        names: dict[int, str] = {}
        for sid, schema in summary.schemas.items():
            name = normalize_msgtype(schema.name)
            text = schema.data.decode()
            try:
                if schema.encoding == "ros2idl":
                    parts = text.split(_SEP)[1:] if text.startswith(f"{_SEP}IDL: ") else [text]
                    for part in parts:
                        types.update(get_types_from_idl(part.split("\n", 1)[1] if (
                            part.startswith("IDL: ")) else part))  # fmt: skip
                else:
                    types.update(get_types_from_msg(text, name))
            except Exception as err:  # rosbags' parser raises its own classes
                raise DataError(f"{self.path}: MCAP schema {schema.name} ({schema.encoding}) "
                                f"does not parse: {_cause(err)}") from err
            names[sid] = name
        store = get_typestore(Stores.EMPTY)
        store.register(types)
        return store, {cid: names[c.schema_id] for cid, c in summary.channels.items()}

    def _digest(self, cid: int) -> str:
        """The definition digest of a channel's type (ROS1: the md5sum a bag's connection
        carries, checked against the channel's `md5sum` metadata when given; ROS 2: RIHS01)."""
        msgtype = self._types[cid]
        if self.is2:
            return str(self.typestore.hash_rihs01(msgtype))
        md5 = str(self.typestore.generate_msgdef(msgtype)[1])
        given = self._channels[cid].metadata.get("md5sum")
        if given and given != "*" and given != md5:
            raise DataError(f"{self.path}: {self._channels[cid].topic}: the schema of {msgtype} "
                            f"has md5sum {md5}, the channel's metadata says {given}")
        return md5

    def topics(self) -> dict[str, str]:
        """Topic -> message type, in channel order."""
        return {c.topic: self._types[cid] for cid, c in self._channels.items()}

    @property
    def latched(self) -> frozenset[str]:
        """Topics of latched channels (channel metadata `latching`: "1" or "true", as `mcap
        convert` copies it from the bag's connection header)."""
        return frozenset(c.topic for c in self._channels.values()
                         if c.metadata.get("latching", "").lower() in ("1", "true"))

    def times(self) -> dict[str, tuple[str, int, I64 | None]]:
        """Topic -> (message type, message count, sorted log times from the message index;
        None when a chunk's index is missing or unreadable: the count is then the summary's
        statistics')."""
        index = self._entries() if self._indexed else {}
        complete = self._indexed and not self._lost
        stats = self._summary.statistics
        counts = stats.channel_message_counts if stats is not None else {}
        out: dict[str, list[I64]] = {}
        n: dict[str, int] = {}
        for cid, channel in self._channels.items():
            out.setdefault(channel.topic, []).append(
                np.fromiter((e[0] for e in index.get(cid, [])), np.int64))
            n[channel.topic] = n.get(channel.topic, 0) + int(counts.get(cid, 0))
        types = self.topics()
        return {t: (types[t], int(sum(x.size for x in p)), np.sort(np.concatenate(p)))
                if complete else (types[t], n[t], None) for t, p in out.items()}

    def messages(self, topics: Collection[str], start: int | None,
                 on_damage: Callable[[DamagedRegion], None]) -> Iterator[Raw]:  # fmt: skip
        """Raw messages of `topics` in log-time order from `start` ns; a damaged chunk is
        reported to `on_damage` and skipped. A file without message indexes (unchunked, or
        written without them) is read front to back instead."""
        wanted = set(topics)
        cids = [cid for cid, c in self._channels.items() if c.topic in wanted]
        if not cids:
            return
        if not self._indexed:
            yield from self._linear(cids, start, on_damage)
            return
        index = self._entries()
        for chunk, why in self._lost.items():
            self._report(chunk, set(cids), start, on_damage, f"message index unreadable: {why}")
        tagged = [_tag(index.get(cid, []), cid) for cid in cids]
        for entry, cid in heapq.merge(*tagged, key=lambda pair: pair[0][0]):
            if (start is not None and entry[0] < start) or entry[1] in self._bad:
                continue
            data, verified = self._load(entry[1], set(cids), start, on_damage)
            if data is None:
                continue
            raw = self._record(data, entry, cid, on_damage)
            if raw is not None:
                channel = self._channels[cid]
                yield (channel.topic, self._types[cid], raw[0], raw[1], self._digests[cid],
                       verified)  # fmt: skip

    def _linear(self, cids: list[int], start: int | None,
                on_damage: Callable[[DamagedRegion], None]) -> Iterator[Raw]:  # fmt: skip
        """Messages read front to back by the `mcap` reader (log-time order); a read error
        ends them with a region of unknown extent."""
        assert self._f is not None
        self._f.seek(0)
        topics = [self._channels[cid].topic for cid in cids]
        last = start or 0
        try:
            for _, channel, message in make_reader(self._f).iter_messages(
                    topics=topics, start_time=start, log_time_order=True):  # fmt: skip
                last = int(message.log_time)
                yield (channel.topic, self._types[channel.id], last, bytes(message.data),
                       self._digests[channel.id], False)  # fmt: skip
        except _CHUNK_ERRORS as err:
            on_damage(DamagedRegion(self.name, 0, 0, tuple(sorted(set(topics))), last,
                                    END_OF_TIME, UNKNOWN, f"reading stopped: {_cause(err)}"))

    def _entries(self) -> dict[int, list[Entry]]:
        """Channel id -> its messages, by log time (stable: chunk order, then index order)."""
        if self._index is not None:
            return self._index
        found: dict[int, list[Entry]] = {}
        assert self._f is not None
        for n, chunk in enumerate(self._chunks):
            try:
                for cid, pairs in _message_index(self._f, chunk):
                    found.setdefault(cid, []).extend((t, n, o) for t, o in pairs)
            except _CHUNK_ERRORS as err:
                self._lost[n] = _cause(err)
        self._index = {cid: sorted(v, key=lambda e: e[0]) for cid, v in found.items()}
        return self._index

    def _load(self, n: int, cids: set[int], start: int | None,
              on_damage: Callable[[DamagedRegion], None]) -> tuple[bytes | None, bool]:  # fmt: skip
        """The records of chunk `n`, decompressed and CRC-checked (cached), and whether a CRC
        vouched for them; None and a region when the chunk is damaged."""
        if self._cached[0] == n:
            return self._cached[1], self._cached[2]
        head = self._chunks[n]
        assert self._f is not None
        data: bytes | None
        try:
            self._f.seek(head.chunk_start_offset + _RECORD.size)
            chunk = Chunk.read(ReadDataStream(self._f))
            data = _decompress(chunk)
            if len(data) != chunk.uncompressed_size:
                raise ValueError(f"{len(data)} bytes decompressed, the chunk says "
                                 f"{chunk.uncompressed_size}")  # fmt: skip
            if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
                raise ValueError("CRC mismatch of the decompressed records")
            verified = bool(chunk.uncompressed_crc)
        except _CHUNK_ERRORS as err:
            self._bad.add(n)
            self._report(n, cids, start, on_damage, _cause(err))
            data, verified = None, False
        self._cached = (n, data, verified)
        return data, verified

    def _record(self, data: bytes, entry: Entry, cid: int,
                on_damage: Callable[[DamagedRegion], None]) -> tuple[int, bytes] | None:
        """(log time, payload) of the message record at `entry.offset`; None and a
        one-message region when it is garbage."""
        offset = entry[2]
        try:
            op, length = _RECORD.unpack_from(data, offset)
            if op != _OP_MESSAGE or length < _MESSAGE.size:
                raise ValueError(f"record op {op:#x} where a message was indexed")
            channel, _, log_time, _ = _MESSAGE.unpack_from(data, offset + _RECORD.size)
            end = offset + _RECORD.size + length
            if channel != cid or end > len(data):
                raise ValueError(f"record of channel {channel}, {end - len(data)} bytes past the "
                                 f"chunk, where channel {cid} was indexed")  # fmt: skip
        except (ValueError, struct.error) as err:
            head = self._chunks[entry[1]]
            on_damage(DamagedRegion(
                self.name, head.chunk_start_offset, head.chunk_start_offset + head.chunk_length,
                (self._channels[cid].topic,), entry[0], entry[0], 1,
                f"message record at offset {offset} of the chunk at byte "
                f"{head.chunk_start_offset}: {_cause(err)}"))  # fmt: skip
            return None
        return int(log_time), data[offset + _RECORD.size + _MESSAGE.size:end]

    def _report(self, n: int, cids: set[int], start: int | None,
                on_damage: Callable[[DamagedRegion], None], cause: str) -> None:  # fmt: skip
        """Report chunk `n` as damaged with what its index says it held (every topic it held,
        when it held a requested one)."""
        head = self._chunks[n]
        if not cids.intersection(head.message_index_offsets):
            return
        held = [cid for cid in head.message_index_offsets if cid in self._channels]
        index = self._index or {}
        times = [e[0] for cid in held for e in index.get(cid, [])
                 if e[1] == n and (start is None or e[0] >= start)]  # fmt: skip
        first = min(times) if times else head.message_start_time
        last = max(times) if times else head.message_end_time
        if start is not None and last < start:
            return
        topics = tuple(sorted({self._channels[cid].topic for cid in held}))
        on_damage(DamagedRegion(
            self.name, head.chunk_start_offset, head.chunk_start_offset + head.chunk_length,
            topics, first, last, len(times) if n not in self._lost else UNKNOWN,
            f"chunk at byte {head.chunk_start_offset}: {cause}"))  # fmt: skip

    def close(self) -> None:
        """Release the file."""
        if self._f is not None:
            self._f.close()
            self._f = None


def _tag(entries: list[Entry], cid: int) -> Iterator[tuple[Entry, int]]:
    """(index entry, channel id) for each entry of one channel."""
    for entry in entries:
        yield entry, cid


def _decompress(chunk: Chunk) -> bytes:
    """A chunk's records, decompressed."""
    if chunk.compression == "zstd":
        return bytes(zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size))  # fmt: skip
    if chunk.compression == "lz4":
        return bytes(lz4.frame.decompress(chunk.data))
    return bytes(chunk.data)


def _message_index(f: IO[bytes], chunk: ChunkIndex) -> Iterator[tuple[int, Any]]:
    """(channel id, (N, 2) log time / offset pairs) of each message index record of a chunk."""
    for cid, offset in chunk.message_index_offsets.items():
        f.seek(offset)
        head = f.read(_INDEX_HEAD.size)
        if len(head) < _INDEX_HEAD.size:
            raise EOFError(f"message index of channel {cid} at byte {offset} cut short")
        op, _, channel, size = _INDEX_HEAD.unpack(head)
        if op != _OP_MESSAGE_INDEX or channel != cid:
            raise ValueError(f"no message index of channel {cid} at byte {offset}")
        body = f.read(size)
        if len(body) != size or size % 16:
            raise EOFError(f"message index of channel {cid} at byte {offset} cut short")
        pairs = np.frombuffer(body, dtype="<u8").reshape(-1, 2).astype(np.int64)
        yield cid, pairs.tolist()


def _cause(err: BaseException) -> str:
    """`Type: message` of an exception, on one line."""
    return f"{type(err).__name__}: {err}".splitlines()[0] if str(err) else type(err).__name__
