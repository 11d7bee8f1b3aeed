"""Shard files of raw (uncompressed) cache arrays, written in one pass, optionally in the
background.

A raw array here is sharded by views with inner chunks (1, B, *rest): B rows of a view's
first axis per chunk (B = all of them for latents and images, CELL_BLOCK cells for the
packed h_cells), each chunk followed by its CRC32C (the `crc32c` codec). Each shard file is
the stored chunks, each starting at a multiple of `CHUNK_ALIGN` bytes, plus the index of
`store.raw_shard`, written to a temporary name and renamed, so a shard is replaced whole
(no chunk of an earlier run survives) and a killed writer leaves no partial shard under the
real name. tensorstore and zarr-python read the same values (tested); one pass over the data
is faster (docs/benchmarks.md, "Cache").

`ShardWriter` moves those file writes to background threads (two by default), so the
caller's next validation or packing runs while shards are being written, and the shards
queued when the caller is done are written two at a time: CRC32C and `writev` of one shard
overlap those of the next and the caller's work (both release the GIL: `os.writev`, and the
`crc32c` package of `store.raw_shard.crc32c`).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import numpy as np
import zarr
from zarr.codecs import BytesCodec, Crc32cCodec, Endian, ShardingCodec
from zarr.codecs.sharding import ShardingCodecIndexLocation

from schemas.atomic_io import write_atomic
from store.raw_shard import CRC_BYTES, chunk_stride, crc_bytes_zero_tail, shard_index


def raw_block(arr: zarr.Array[Any]) -> int | None:
    """Rows B of a view's first axis per inner chunk when `arr` is a raw sharded array with
    inner chunks (1, B, *rest) and inner codecs [bytes little-endian, crc32c]; None for any
    other layout."""
    codecs = arr.metadata.codecs  # type: ignore[union-attr]
    if len(codecs) != 1 or not isinstance(codecs[0], ShardingCodec) or arr.ndim < 2:
        return None
    shard = codecs[0]
    chunk = tuple(shard.chunk_shape)
    raw = (chunk[0] == 1 and chunk[2:] == tuple(arr.shape[2:])
           and shard.index_location == ShardingCodecIndexLocation.end
           and [type(c) for c in shard.codecs] == [BytesCodec, Crc32cCodec]
           and [type(c) for c in shard.index_codecs] == [BytesCodec, Crc32cCodec]
           and all(getattr(c, "endian", None) in (None, Endian.little)
                   for c in (*shard.codecs, *shard.index_codecs[:1]))
           and arr.dtype.byteorder in ("=", "<", "|") and sys.byteorder == "little")
    return int(chunk[1]) if raw else None


def view_blocks(view: np.ndarray, block: int, n_blocks: int) -> list[np.ndarray | None]:
    """The `n_blocks` inner chunks of one view holding its first r rows (view: (r, *rest)):
    the rows in blocks of `block` (views of `view`, no copy), the last one possibly short
    (zarr stores whole chunks: `write_shard_file` writes its zero tail), then None (not
    stored) for the blocks past them."""
    stored: list[np.ndarray | None] = [view[j:j + block] for j in range(0, len(view), block)]
    return stored + [None] * (n_blocks - len(stored))


def shard_chunks(views: Sequence[np.ndarray], per: int, block: int,
                 rows: int) -> list[np.ndarray | None]:
    """Inner chunks of one shard in C order: `per` views x ceil(rows / block) blocks;
    views[i] (r_i, *rest) holds view i's first r_i rows, views past len(views) store none."""
    n_blocks = -(-rows // block)
    chunks = [c for view in views for c in view_blocks(view, block, n_blocks)]
    return chunks + [None] * (n_blocks * (per - len(views)))


def chunk_buffers(chunk: np.ndarray, chunk_nbytes: int, zeros: memoryview, pad: bytes
                  ) -> list[bytes | memoryview]:
    """The buffers of one stored chunk: its bytes, the zero tail of a short last block (up to
    `chunk_nbytes`, taken from `zeros`), then its CRC32C (of data and tail) and `pad`."""
    data = np.ascontiguousarray(chunk).data.cast("B")
    tail = zeros[:chunk_nbytes - len(data)]
    return [data, tail, crc_bytes_zero_tail(data, tail) + pad]


def write_shard_file(path: Path, chunks: list[np.ndarray | None], chunk_nbytes: int) -> None:
    """Write one shard file atomically: the present chunks, each with its CRC32C and zero
    padding to `chunk_stride`, then their index, in as few `writev` calls as the system
    allows: the same bytes written chunk by chunk with a small CRC write after each were
    read back from the page cache 1.12-1.49x slower than written at once (docs/benchmarks.md,
    "Chunk checksums"). A short chunk's zero rows are written from one shared zero buffer
    and its CRC extended over them (no padded copy of the chunk)."""
    pad = bytes(chunk_stride(chunk_nbytes + CRC_BYTES) - chunk_nbytes - CRC_BYTES)
    zeros = memoryview(bytes(chunk_nbytes))
    buffers: list[bytes | memoryview] = []
    for chunk in chunks:
        if chunk is not None:
            buffers += chunk_buffers(chunk, chunk_nbytes, zeros, pad)
    buffers.append(shard_index([c is not None for c in chunks], chunk_nbytes + CRC_BYTES))

    def write(f: BinaryIO) -> None:
        f.flush()
        writev_all(f.fileno(), buffers)

    write_atomic(path, write)


IOV_MAX = os.sysconf("SC_IOV_MAX") if hasattr(os, "sysconf") else 1024
"""Most buffers one `writev` takes."""


def writev_all(fd: int, buffers: Sequence[bytes | memoryview]) -> None:
    """Write `buffers` to `fd` in order with `writev`, up to IOV_MAX at a time; a short write
    resumes where it stopped."""
    views = [memoryview(b).cast("B") for b in buffers if len(b)]
    first = 0
    while first < len(views):
        done = os.writev(fd, views[first:first + IOV_MAX])
        while done and first < len(views):
            if done >= len(views[first]):
                done -= len(views[first])
                first += 1
            else:
                views[first] = views[first][done:]
                done = 0


def write_raw(arr: zarr.Array[Any], start: int, views: Sequence[np.ndarray], block: int) -> None:
    """Write views [start, start + len(views)) of a raw array (see `raw_block`) shard by
    shard; views[i] (r_i, *rest) are view start + i's first r_i rows, stored dtype, finite.

    The region must be shard-aligned (checked by the caller)."""
    assert arr.shards is not None
    per, rows = arr.shards[0], arr.shape[1]
    chunk_nbytes = block * int(np.prod(arr.shape[2:], dtype=np.int64)) * arr.dtype.itemsize
    folder = Path(str(arr.store.root)) / arr.path  # type: ignore[attr-defined]
    for first in range(0, len(views), per):
        key = arr.metadata.encode_chunk_key(((start + first) // per, *(0,) * (arr.ndim - 1)))
        chunks = shard_chunks(views[first:first + per], per, block, rows)
        write_shard_file(folder / key, chunks, chunk_nbytes)


WRITER_THREADS = 2
"""Background threads of a `ShardWriter`. Two let the shards still queued when the caller is
done be written at once, where a core is free; on the shared 2-core machine at load 3-5 the
cache benchmark's writes were alike with one or two (paired medians 1.18x and 0.96x over 20
and 30 alternated pairs, the same CPU seconds; docs/benchmarks.md, "Cache", 2026-11-28)."""


class ShardWriter:
    """Runs submitted writes on `threads` background threads, started in submission order;
    leaving the `with` block waits for all of them and raises the first error (after
    waiting, so no write is left running). Writes submitted to one writer must touch
    distinct files (each is one shard file, or one tensorstore region of whole shards)."""

    def __init__(self, threads: int = WRITER_THREADS) -> None:
        self._pool = ThreadPoolExecutor(max_workers=threads,
                                        thread_name_prefix="m3gd-shard-writer")
        self._pending: list[Future[None]] = []

    def submit(self, fn: Callable[..., None], *args: Any) -> None:
        """Queue fn(*args); it starts once the writes queued before it have started."""
        self._pending.append(self._pool.submit(fn, *args))

    def wait(self) -> None:
        """Block until every queued write is done; raise the first error."""
        pending, self._pending = self._pending, []
        errors = [e for e in (f.exception() for f in pending) if e is not None]
        if errors:
            raise errors[0]

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, err: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            if kind is None:
                self.wait()
            else:  # the body's error wins: writes not yet started are dropped (each file is
                # written to a temporary name and renamed, so none is left half-written), the
                # running ones finish
                for f in self._pending:
                    f.cancel()
                for f in self._pending:
                    if not f.cancelled():
                        f.exception()
        finally:
            self._pool.shutdown(wait=True)


def run_or_submit(writer: ShardWriter | None, fn: Callable[..., None], *args: Any) -> None:
    """fn(*args) now, or queued on `writer`."""
    if writer is None:
        fn(*args)
    else:
        writer.submit(fn, *args)
