"""The on-disk layout of m3gd's Zarr v3 arrays as the pread reader sees it: which codec
chains it reads (`ArrayMeta.parse`), a shard's index, the regular runs of stored chunks, and
the CRC32C check of a chunk (cache format 3).

Pure parsing and checks, no open files (those are `store.shard_reader`'s)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import google_crc32c
import numpy as np
from numpy.typing import NDArray

from schemas.errors import DataError
from store.raw_shard import CRC_BYTES
from store.raw_shard import MISSING as _MISSING

MISSING = int(_MISSING)
"""Offset and nbytes of an inner chunk that is not stored (as a Python int)."""

_INDEX_CODECS = [{"name": "bytes", "configuration": {"endian": "little"}}, {"name": "crc32c"}]
_BYTES_LE: dict[str, Any] = {"name": "bytes", "configuration": {"endian": "little"}}
_BYTES_ANY: dict[str, Any] = {"name": "bytes"}


class CorruptChunkError(DataError):
    """A stored chunk whose CRC32C does not match its bytes (damaged at rest): its data is
    never returned. Permanent; `m3gd verify` finds every such chunk and marks its items
    for the next run to redo."""


def crc_ok(parts: list[NDArray[np.uint8]], stored: NDArray[np.uint8]) -> bool:
    """Whether the CRC32C of `parts` (concatenated) equals the 4 little-endian bytes
    `stored`."""
    crc = int(google_crc32c.value(parts[0]))
    for part in parts[1:]:
        crc = int(google_crc32c.extend(crc, part))
    return crc == int.from_bytes(stored.tobytes(), "little")


@dataclass(frozen=True)
class ArrayMeta:
    """What the reader needs of one array's zarr.json.

    shape: full array shape; file_views: views per file (shard or chunk) on axis 0;
    chunk: inner chunk shape (= (file_views, ...) for unsharded arrays); sharded; zstd;
    crc: every stored chunk ends with its CRC32C (4 bytes).
    """

    shape: tuple[int, ...]
    dtype: np.dtype[Any]
    file_views: int
    chunk: tuple[int, ...]
    sharded: bool
    zstd: bool
    crc: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "chunks_per_view", int(np.prod(
            [s // c for s, c in zip(self.view_shape, self.chunk[1:], strict=True)])))
        object.__setattr__(self, "chunk_nbytes", int(np.prod(self.chunk)) * self.dtype.itemsize)
        object.__setattr__(self, "stored_nbytes",
                           self.chunk_nbytes + (CRC_BYTES if self.crc else 0))

    @classmethod
    def parse(cls, meta: dict[str, Any]) -> ArrayMeta | None:
        """Parsed metadata, or None when the array uses a layout this reader does not read."""
        try:
            grid = list(meta["chunk_grid"]["configuration"]["chunk_shape"])
            key = meta.get("chunk_key_encoding", {})
            if key.get("name") != "default" or key.get("configuration", {}).get(
                    "separator", "/") != "/" or meta.get("fill_value") not in (0, 0.0, False):
                return None
            shape = tuple(int(s) for s in meta["shape"])
            dtype = np.dtype(meta["data_type"]).newbyteorder("<")
            codecs = [_BYTES_LE if c == _BYTES_ANY and dtype.itemsize == 1 else c
                      for c in meta["codecs"]]  # one-byte values: bytes has no endianness
            if len(codecs) == 1 and codecs[0]["name"] == "sharding_indexed":
                conf = codecs[0]["configuration"]
                inner, crc = _strip_crc([_BYTES_LE if c == _BYTES_ANY and dtype.itemsize == 1
                                         else c for c in conf["codecs"]])
                zstd = len(inner) == 2 and inner[1]["name"] == "zstd"
                if (inner[0] != _BYTES_LE or len(inner) > 2 or (len(inner) == 2 and not zstd)
                        or conf["index_codecs"] != _INDEX_CODECS
                        or conf.get("index_location", "end") != "end"
                        or any(s != c for s, c in zip(grid[1:], shape[1:], strict=True))):
                    return None
                return cls(shape, dtype, int(grid[0]), tuple(int(c) for c in conf["chunk_shape"]),
                           True, zstd, crc)
            inner, crc = _strip_crc(codecs)
            if inner == [_BYTES_LE] and list(grid[1:]) == list(shape[1:]):
                return cls(shape, dtype, int(grid[0]), tuple(int(c) for c in grid), False, False,
                           crc)
        except (KeyError, TypeError, IndexError, ValueError):
            return None
        return None

    @property
    def view_shape(self) -> tuple[int, ...]:
        """Shape of one view (the array shape without axis 0)."""
        return self.shape[1:]

    chunks_per_view: int = field(init=False)
    """Inner chunks one view spans (1 unless a view is split, like h_cells' cell blocks)."""
    chunk_nbytes: int = field(init=False)
    """Bytes of one decoded inner chunk."""
    stored_nbytes: int = field(init=False)
    """Bytes of one stored raw chunk (its CRC32C included)."""


def _strip_crc(codecs: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], bool]:
    """(the codec chain without a final crc32c, whether it had one)."""
    if codecs and codecs[-1].get("name") == "crc32c":
        return codecs[:-1], True
    return codecs, False


def index_pairs(shard: bytes, n: int) -> NDArray[np.uint64]:
    """(n, 2) uint64 (offset, nbytes) of the `n` inner chunks from the index at the end of
    `shard` (a shard's bytes, or its index alone: 16 n bytes and the index's CRC32C, which is
    not checked here); MISSING twice for a chunk not stored."""
    return np.frombuffer(shard[len(shard) - (16 * n + 4):len(shard) - 4], "<u8").reshape(n, 2)


def read_index(fd: int, size: int, meta: ArrayMeta, path: str) -> list[tuple[int, int]]:
    """The (offset, nbytes) pairs of every inner chunk from the index at the end of a shard
    file, CRC-checked."""
    grid = [s // c for s, c in zip((meta.file_views, *meta.view_shape), meta.chunk, strict=True)]
    n = int(np.prod(grid))
    nbytes = 16 * n + 4
    if size < nbytes:
        raise ValueError(f"{path}: {size} bytes, too short for a shard index of {n} chunks")
    raw = os.pread(fd, nbytes, size - nbytes)
    if int(google_crc32c.value(raw[:-4])) != int.from_bytes(raw[-4:], "little"):
        raise ValueError(f"{path}: shard index CRC32C mismatch (damaged or partly written)")
    return [(int(o), int(b)) for o, b in index_pairs(raw, n).tolist()]


MAX_GAP = 256
"""Most bytes between two stored chunks (CRC and padding) that a run read skips over; chunks
further apart are read one preadv each."""


def regular_runs(entries: list[tuple[int, int]], stored: int
          ) -> list[tuple[int, int, int, int]] | None:
    """[(first chunk, offset, chunks, stride)]: one run when every entry is stored, `stored`
    bytes, at one stride from `stored` to `stored + MAX_GAP` bytes (one entry: stride
    `stored`); None otherwise (each chunk is then read on its own)."""
    first = entries[0][0]
    stride = entries[1][0] - first if len(entries) > 1 else stored
    if stored <= stride <= stored + MAX_GAP and all(
            off == first + i * stride and n == stored for i, (off, n) in enumerate(entries)):
        return [(0, first, len(entries), stride)]
    return None
