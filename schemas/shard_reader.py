"""A pread reader of m3gd's Zarr v3 arrays that keeps files open and shard indexes parsed.

tensorstore reopens a shard file and rereads its index on every read; for a clip (a few views
of five arrays) that was ~12 opens and ~16 reads (docs/benchmarks.md, issue 21). This reader
opens each shard file once for its lifetime, parses its index once (CRC32C checked), and reads
each view with one `os.preadv` straight into the caller's output array: the view's inner
chunk(s) are contiguous in a shard written by m3gd, so one call moves them (scattered into
the rows wanted and a scratch tail when a packed view's last chunk is partly padding).

Only the codec chains m3gd writes are read here (`schemas.cache_layout`): sharded with inner
[bytes little-endian] or [bytes little-endian, zstd] and index [bytes, crc32c] at the end, or
unsharded [bytes little-endian]; `ArrayMeta.parse` returns None for anything else and
callers fall back to tensorstore. The on-disk format is unchanged: zarr-python, xarray and
tensorstore read the same files.

Invalidation: every read stats the shard's path (one `stat`, no open) and reopens when its
(inode, mtime, size) changed, so a shard replaced by rename (the writers' temp file +
rename) is never read through a stale handle or index. A missing shard or chunk reads as the
fill value (0), like every Zarr reader.
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import google_crc32c
import numpy as np
import zstandard
from numpy.typing import NDArray

from schemas.raw_shard import MISSING as _MISSING

MISSING = int(_MISSING)

_INDEX_CODECS = [{"name": "bytes", "configuration": {"endian": "little"}}, {"name": "crc32c"}]
_BYTES_LE = {"name": "bytes", "configuration": {"endian": "little"}}
SMALL_CHUNK = 64 << 10
"""Inner chunks up to this many bytes (g: 9 KiB a view; K, poses: a few KiB a shard) are
kept decoded by a reader (LRU, `chunk_cache_bytes` in all): decoding g's zstd was ~10 % of
a clip read. Larger chunks (latents, h rows) are read from the page cache every time."""


@dataclass(frozen=True)
class ArrayMeta:
    """What the reader needs of one array's zarr.json.

    shape: full array shape; file_views: views per file (shard or chunk) on axis 0;
    chunk: inner chunk shape (= (file_views, ...) for unsharded arrays); sharded; zstd.
    """

    shape: tuple[int, ...]
    dtype: np.dtype[Any]
    file_views: int
    chunk: tuple[int, ...]
    sharded: bool
    zstd: bool

    def __post_init__(self) -> None:
        object.__setattr__(self, "chunks_per_view", int(np.prod(
            [s // c for s, c in zip(self.view_shape, self.chunk[1:], strict=True)])))
        object.__setattr__(self, "chunk_nbytes", int(np.prod(self.chunk)) * self.dtype.itemsize)

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
            codecs = meta["codecs"]
            if len(codecs) == 1 and codecs[0]["name"] == "sharding_indexed":
                conf = codecs[0]["configuration"]
                inner = conf["codecs"]
                zstd = len(inner) == 2 and inner[1]["name"] == "zstd"
                if (inner[0] != _BYTES_LE or len(inner) > 2 or (len(inner) == 2 and not zstd)
                        or conf["index_codecs"] != _INDEX_CODECS
                        or conf.get("index_location", "end") != "end"
                        or any(s != c for s, c in zip(grid[1:], shape[1:], strict=True))):
                    return None
                return cls(shape, dtype, int(grid[0]), tuple(int(c) for c in conf["chunk_shape"]),
                           True, zstd)
            if codecs == [_BYTES_LE] and list(grid[1:]) == list(shape[1:]):
                return cls(shape, dtype, int(grid[0]), tuple(int(c) for c in grid), False, False)
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


@dataclass
class _OpenFile:
    """One open shard (or chunk) file: descriptor, identity, and parsed index (sharded)."""

    fd: int
    ident: tuple[int, int, int]
    index: list[tuple[int, int]] | None


def _ident(st: os.stat_result) -> tuple[int, int, int]:
    """(inode, mtime ns, size): changes when a file is replaced by rename or rewritten."""
    return (st.st_ino, st.st_mtime_ns, st.st_size)


class ShardReader:
    """Reads views of m3gd's cache arrays with cached file handles and shard indexes.

    Not thread-safe; one per process or DataLoader worker (handles do not survive a pickle:
    a copy starts empty). `opens` counts files opened (zarr.json and shard files), for the
    benchmark. At most `max_files` shard files stay open (least recently used closed first).
    """

    def __init__(self, max_files: int = 64, prefetch_clips: bool = True,
                 chunk_cache_bytes: int = 64 << 20) -> None:
        self.max_files = max_files
        self.prefetch_clips = prefetch_clips
        self.chunk_cache_bytes = chunk_cache_bytes
        self._chunks: OrderedDict[tuple[str, int], tuple[tuple[int, int, int],
                                                         NDArray[np.uint8]]] = OrderedDict()
        self._chunk_bytes = 0
        self.opens = 0
        self.misses = 0
        self._meta: dict[Path, ArrayMeta | None] = {}
        self._paths: dict[tuple[Path, int], str] = {}
        self._files: OrderedDict[str, _OpenFile] = OrderedDict()
        self._zstd = zstandard.ZstdDecompressor()
        self._on_miss: Callable[[], None] | None = None

    @contextmanager
    def on_first_miss(self, hook: Callable[[], None]) -> Iterator[None]:
        """Within the block, reads first try the page cache alone (`RWF_NOWAIT`); the first
        one that would wait for the disk calls `hook` once (e.g. `prefetch` of everything
        the caller is about to read), then waits. Warm reads cost nothing extra."""
        self._on_miss = hook if self.prefetch_clips else None
        try:
            yield
        finally:
            self._on_miss = None

    def __getstate__(self) -> dict[str, Any]:
        return {"max_files": self.max_files, "prefetch_clips": self.prefetch_clips,
                "chunk_cache_bytes": self.chunk_cache_bytes}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state)  # type: ignore[misc]

    def __enter__(self) -> ShardReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close every open file (the reader stays usable and reopens on demand)."""
        while self._files:
            os.close(self._files.popitem()[1].fd)

    def meta(self, array: Path) -> ArrayMeta | None:
        """Parsed metadata of the array at `array` (read once), None if not readable here."""
        if array not in self._meta:
            self.opens += 1
            self._meta[array] = ArrayMeta.parse(json.loads((array / "zarr.json").read_text()))
        return self._meta[array]

    def prefetch(self, array: Path, frames: list[int]) -> None:
        """Ask the kernel to start reading the stored bytes of views `frames` now
        (`posix_fadvise(WILLNEED)`, asynchronous): a clip's reads from several files then
        overlap on the disk instead of waiting one after another (cold page cache)."""
        meta = self.meta(array)
        if meta is None:
            return
        files = self._files_of(array, meta, frames)
        for f in frames:
            opened = files[f // meta.file_views][1]
            if opened is None:
                continue
            local = f % meta.file_views
            if opened.index is None:
                size = meta.chunk_nbytes // meta.file_views
                os.posix_fadvise(opened.fd, local * size, size, os.POSIX_FADV_WILLNEED)
                continue
            first = local * meta.chunks_per_view
            stored = [e for e in opened.index[first:first + meta.chunks_per_view]
                      if e[0] != MISSING]
            if stored:
                start = min(o for o, _ in stored)
                stop = max(o + n for o, n in stored)
                os.posix_fadvise(opened.fd, start, stop - start, os.POSIX_FADV_WILLNEED)

    def read_views(self, array: Path, frames: list[int]) -> NDArray[Any]:
        """Views `frames` (k,) of the array at `array`: (k, *view_shape), its dtype."""
        meta = self._checked_meta(array)
        out = np.empty((len(frames), *meta.view_shape), meta.dtype)
        files = self._files_of(array, meta, frames)
        for i, f in enumerate(frames):
            self._read_view(files[f // meta.file_views], meta, f, out[i:i + 1],
                            meta.chunks_per_view)  # a slice: out[i] of 0-d views is a copy
        return out

    def read_rows(self, array: Path, frames: list[int], counts: NDArray[Any]) -> NDArray[Any]:
        """Rows [0, counts[i]) of view frames[i] of a packed-rows array (N, cells, C), all
        views' rows stacked: (sum(counts), C), view after view (schemas.packed_cells)."""
        meta = self._checked_meta(array)
        counts = np.asarray(counts, np.int64)
        if len(counts) != len(frames):
            raise ValueError(f"{array}: {len(counts)} row counts for {len(frames)} views")
        out = np.empty((int(counts.sum()), *meta.view_shape[1:]), meta.dtype)
        files = self._files_of(array, meta, frames)
        start, rows_per_chunk = 0, meta.chunk[1]
        for f, n in zip(frames, counts.tolist(), strict=True):
            if not 0 <= n <= meta.view_shape[0]:
                raise ValueError(f"{array}: view {f}: {n} rows of {meta.view_shape[0]}")
            self._read_view(files[f // meta.file_views], meta, f, out[start:start + n],
                            -(-n // rows_per_chunk))
            start += n
        return out

    def _checked_meta(self, array: Path) -> ArrayMeta:
        meta = self.meta(array)
        if meta is None:
            raise ValueError(f"{array}: codecs or chunking this reader does not read")
        return meta

    def _files_of(self, array: Path, meta: ArrayMeta, frames: list[int]
                  ) -> dict[int, tuple[str, _OpenFile | None]]:
        """The open file (None: not stored) of every file number the views `frames` lie in,
        each checked once against its path (one stat)."""
        out = {}
        for f in frames:
            if not 0 <= f < meta.shape[0]:
                raise IndexError(f"{array}: view {f} out of range 0..{meta.shape[0] - 1}")
            file_no = f // meta.file_views
            if file_no not in out:
                path = self._paths.get((array, file_no))
                if path is None:
                    key = "/".join(["c", str(file_no), *["0"] * (len(meta.shape) - 1)])
                    path = self._paths[(array, file_no)] = str(array / key)
                out[file_no] = (path, self._file(path, meta))
        return out

    def _file(self, path: str, meta: ArrayMeta) -> _OpenFile | None:
        """The open file at `path` (reopened if replaced since), or None if it does not exist."""
        try:
            ident = _ident(os.stat(path))
        except FileNotFoundError:
            self._drop(path)
            return None
        cached = self._files.get(path)
        if cached is not None and cached.ident == ident:
            self._files.move_to_end(path)
            return cached
        self._drop(path)
        fd = os.open(path, os.O_RDONLY)
        self.opens += 1
        try:
            st = os.fstat(fd)  # the identity of what was opened, not of what was stat-ed
            index = _read_index(fd, st.st_size, meta, path) if meta.sharded else None
        except BaseException:
            os.close(fd)
            raise
        opened = _OpenFile(fd, _ident(st), index)
        self._files[path] = opened
        while len(self._files) > self.max_files:
            os.close(self._files.popitem(last=False)[1].fd)
        return opened

    def _drop(self, path: str) -> None:
        """Close and forget the handle on `path`, if any."""
        old = self._files.pop(path, None)
        if old is not None:
            os.close(old.fd)

    def _pread(self, fd: int, buffers: list[NDArray[np.uint8]], offset: int, nbytes: int,
               path: str) -> None:
        """Fill `buffers` (total `nbytes`) from `offset`: one preadv (two after a page-cache
        miss inside `on_first_miss`, which runs its hook in between); raise if short."""
        got = 0
        if self._on_miss is not None:
            try:
                got = os.preadv(fd, [b.data for b in buffers], offset, os.RWF_NOWAIT)
            except BlockingIOError:
                got = 0
            if got == nbytes:
                return
            hook, self._on_miss = self._on_miss, None
            self.misses += 1
            hook()
            buffers = _skip(buffers, got)
        done = got + os.preadv(fd, [b.data for b in buffers], offset + got)
        if done != nbytes:
            raise ValueError(f"{path}: short read at {offset} ({done} of {nbytes} bytes)")

    def _read_view(self, file: tuple[str, _OpenFile | None], meta: ArrayMeta, frame: int,
                   dest: NDArray[Any], n_chunks: int) -> None:
        """Fill `dest` (C-contiguous: the first `n_chunks` inner chunks of view `frame`,
        truncated to dest's size) from the view's file; zeros where nothing is stored."""
        path, opened = file
        local = frame % meta.file_views
        target = dest.reshape(-1).view(np.uint8)
        if opened is None or n_chunks == 0:
            target[:] = 0
        elif meta.chunks_per_view == 1 and meta.chunk_nbytes <= SMALL_CHUNK:
            self._small_view(path, opened, meta, local, target)  # g, K, poses: kept decoded
        elif opened.index is None:  # unsharded raw chunk of file_views views
            self._pread(opened.fd, [target], local * target.nbytes, target.nbytes, path)
        elif meta.zstd:
            first = local * meta.chunks_per_view
            self._read_zstd(opened.fd, opened.index[first:first + n_chunks], meta, target, path)
        else:
            first = local * meta.chunks_per_view
            self._read_raw(opened.fd, opened.index[first:first + n_chunks], meta.chunk_nbytes,
                           target, path)

    def _small_view(self, path: str, opened: _OpenFile, meta: ArrayMeta, local: int,
                    target: NDArray[np.uint8]) -> None:
        """View `local` of a file whose chunks are small: the decoded chunk comes from the
        reader's chunk cache (valid while the file's identity is unchanged) or is read and
        decoded (zstd) into it. A sharded array's chunk is one view; an unsharded one's is
        the file's `file_views` views."""
        chunk_no = 0 if opened.index is None else local  # one chunk per file, or per view
        key = (path, chunk_no)
        hit = self._chunks.get(key)
        if hit is None or hit[0] != opened.ident:
            hit = (opened.ident, self._decode_chunk(path, opened, meta, chunk_no))
            self._chunks[key] = hit
            self._chunk_bytes += meta.chunk_nbytes
            while self._chunk_bytes > self.chunk_cache_bytes and self._chunks:
                self._chunk_bytes -= self._chunks.popitem(last=False)[1][1].size
        else:
            self._chunks.move_to_end(key)
        size = target.size
        start = local * size if opened.index is None else 0
        target[:] = hit[1][start:start + size]

    def _decode_chunk(self, path: str, opened: _OpenFile, meta: ArrayMeta,
                      chunk_no: int) -> NDArray[np.uint8]:
        """The decoded bytes of inner chunk `chunk_no` of an open file (zeros if missing)."""
        out = np.empty(meta.chunk_nbytes, np.uint8)
        if opened.index is None:
            self._pread(opened.fd, [out], 0, out.size, path)
        elif meta.zstd:
            self._read_zstd(opened.fd, opened.index[chunk_no:chunk_no + 1], meta, out, path)
        else:
            self._read_raw(opened.fd, opened.index[chunk_no:chunk_no + 1], meta.chunk_nbytes,
                           out, path)
        return out

    def forget_chunks(self) -> None:
        """Empty the decoded small-chunk cache (handles and shard indexes stay)."""
        self._chunks.clear()
        self._chunk_bytes = 0

    def _read_raw(self, fd: int, entries: list[tuple[int, int]], chunk_nbytes: int,
                  target: NDArray[np.uint8], path: str) -> None:
        """Raw inner chunks `entries` [(offset, nbytes)] into `target` (bytes past its size go to
        a scratch tail): one preadv when they are stored back to back (as m3gd writes them), else
        one per chunk; zeros for missing ones."""
        first = entries[0][0]
        if all(off == first + i * chunk_nbytes and size == chunk_nbytes
               for i, (off, size) in enumerate(entries)):
            runs = [(0, entries[0][0], len(entries))]
        else:
            runs = [(j, off, 1) for j, (off, _) in enumerate(entries)]
            for off, size in entries:
                if off != MISSING and size != chunk_nbytes:
                    raise ValueError(f"{path}: raw chunk of {size} bytes, expected {chunk_nbytes}")
        for j, offset, n in runs:
            pos, want = j * chunk_nbytes, n * chunk_nbytes
            if pos >= target.size:
                break
            inside = min(want, target.size - pos)
            if offset == MISSING:
                target[pos:pos + inside] = 0
                continue
            buffers = [target[pos:pos + inside]]
            if want > inside:
                buffers.append(np.empty(want - inside, np.uint8))
            self._pread(fd, buffers, offset, want, path)

    def _read_zstd(self, fd: int, entries: list[tuple[int, int]], meta: ArrayMeta,
                   target: NDArray[np.uint8], path: str) -> None:
        """zstd inner chunks `entries` decoded into `target` (one chunk per view: g)."""
        if len(entries) != 1 or target.size != meta.chunk_nbytes:
            raise ValueError(f"{path}: compressed arrays are read one whole chunk per view")
        offset, nbytes = entries[0]
        if offset == MISSING:
            target[:] = 0
            return
        data = np.empty(nbytes, np.uint8)
        self._pread(fd, [data], offset, nbytes, path)
        try:
            decoded = self._zstd.decompress(data.data, max_output_size=target.size)
        except zstandard.ZstdError as err:
            raise ValueError(f"{path}: chunk at {offset}: {err}") from err
        if len(decoded) != target.size:
            raise ValueError(f"{path}: chunk at {offset} decodes to {len(decoded)} bytes, "
                             f"expected {target.size}")
        target[:] = np.frombuffer(decoded, np.uint8)


def _read_index(fd: int, size: int, meta: ArrayMeta, path: str) -> list[tuple[int, int]]:
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
    pairs = np.frombuffer(raw, "<u8", count=2 * n).reshape(n, 2).tolist()
    return [(int(o), int(b)) for o, b in pairs]


def _skip(buffers: list[NDArray[np.uint8]], nbytes: int) -> list[NDArray[np.uint8]]:
    """`buffers` without their first `nbytes` bytes (those already read)."""
    out = []
    for b in buffers:
        if nbytes >= b.size:
            nbytes -= b.size
            continue
        out.append(b[nbytes:])
        nbytes = 0
    return out
