"""The read floor of the cache benchmark, cold page caches and honest file-open counts.

Floor: the same views' bytes (latents, g raw, h's packed rows: exactly what the store holds,
uncompressed) laid out as one contiguous record per view in one file, read with one `preadv`
per view straight into the clip's output arrays from a handle opened once: what MosaicML
Streaming's MDS format does per sample (one pread of a sample's bytes), without its Python
overhead. Nothing reads a clip's bytes with fewer syscalls or copies.

Cold: `drop_page_cache` writes dirty pages back (`os.sync`) and asks the kernel to drop the
cached pages of every file under the given paths (`posix_fadvise(DONTNEED)`), so the next
read comes from the disk. Opens: `OpenCounter` counts every `open` audit event (raised by
`os.open`, `io.open`/`open`, and so by numpy and pathlib), i.e. every file a Python-level
reader opens; the store's reader (`store.shard_reader`) opens files only that way.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from schemas.packed_cells import cell_counts, occupied_cells

FLOOR_NAMES = ("latents_l0", "g", "h_rows")


@dataclass
class FloorFile:
    """One file of per-view records: latents, g, then the view's packed h rows.

    offsets (N,) byte offset of each record; counts (N,) h rows per record; shapes and dtypes
    of one view of latents and g, and the row width and dtype of h.
    """

    path: Path
    offsets: np.ndarray
    counts: np.ndarray
    lat: tuple[tuple[int, ...], np.dtype[Any]]
    g: tuple[tuple[int, ...], np.dtype[Any]]
    row: tuple[int, np.dtype[Any]]
    fd: int = field(default=-1)

    def open(self) -> None:
        """Open the file once (like a loader keeps its shard handles)."""
        if self.fd < 0:
            self.fd = os.open(self.path, os.O_RDONLY)

    def close(self) -> None:
        """Close the handle."""
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def write_floor(path: Path, data: dict[str, np.ndarray]) -> FloorFile:
    """Write `data` (latents (N, C, H, W), g (N, 6, H, W), dense h (N, C_u, H, W)) as one
    record per view; h keeps only the occupied cells' rows (g[:, 0] > 0.5), as stored."""
    lat, g, h = data["latents_l0"], data["g"], data["h"]
    occupied = occupied_cells(g)
    counts = cell_counts(occupied)
    offsets = np.zeros(len(lat), np.int64)
    with path.open("wb") as f:
        for v in range(len(lat)):
            offsets[v] = f.tell()
            rows = np.moveaxis(h[v], 0, -1)[occupied[v]]  # (k, C_u) row-major cells
            for part in (lat[v], g[v], rows):
                f.write(np.ascontiguousarray(part).tobytes())
    return FloorFile(path, offsets, counts, (lat.shape[1:], lat.dtype), (g.shape[1:], g.dtype),
                     (h.shape[1], h.dtype))


def read_floor_clip(floor: FloorFile, frames: list[int]) -> dict[str, np.ndarray]:
    """One clip from the floor file: one preadv per view into stacked latents (k, C, H, W),
    g (k, 6, H, W) and the views' packed rows (sum k_v, C_u)."""
    counts = floor.counts[frames]
    lat = np.empty((len(frames), *floor.lat[0]), floor.lat[1])
    g = np.empty((len(frames), *floor.g[0]), floor.g[1])
    rows = np.empty((int(counts.sum()), floor.row[0]), floor.row[1])
    start = 0
    for i, f in enumerate(frames):
        stop = start + int(counts[i])
        parts = [lat[i], g[i], rows[start:stop]]
        want = sum(p.nbytes for p in parts)
        got = os.preadv(floor.fd, [p.reshape(-1).view(np.uint8).data for p in parts],
                        int(floor.offsets[f]))
        if got != want:
            raise OSError(f"{floor.path}: short read of view {f}")
        start = stop
    return {"latents_l0": lat, "g": g, "h_rows": rows}


def drop_page_cache(*paths: Path) -> None:
    """Flush dirty pages, then drop the cached pages of every file under `paths`."""
    os.sync()
    for root in paths:
        files = [root] if root.is_file() else [p for p in root.rglob("*") if p.is_file()]
        for p in files:
            fd = os.open(p, os.O_RDONLY)
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
            finally:
                os.close(fd)


class OpenCounter:
    """Counts files under `root` opened by Python code in any thread (audit event `open`)
    while active (other files, such as a memory sampler's /proc reads, are not the reader's).

    An audit hook cannot be removed, so one process-wide hook is installed on first use and
    only counts while a counter is active.
    """

    _active: OpenCounter | None = None
    _installed = False

    def __init__(self, root: Path) -> None:
        self.root = os.fspath(root)
        self.opens = 0

    def __enter__(self) -> OpenCounter:
        if not OpenCounter._installed:
            sys.addaudithook(OpenCounter._hook)
            OpenCounter._installed = True
        OpenCounter._active = self
        return self

    def __exit__(self, *exc: object) -> None:
        OpenCounter._active = None

    @staticmethod
    def _hook(event: str, args: tuple[Any, ...]) -> None:
        active = OpenCounter._active
        if event == "open" and active is not None and args and args[0] is not None \
                and not isinstance(args[0], int) \
                and os.fsdecode(args[0]).startswith(active.root):  # an fd is not an open
            active.opens += 1


def timed_clips(read: Any, clips: list[list[int]]) -> float:
    """Seconds `read(frames)` takes over `clips`."""
    t0 = time.perf_counter()
    for frames in clips:
        read(frames)
    return time.perf_counter() - t0


def interleaved(readers: dict[str, Any], clips: list[list[int]], repeats: int,
                cold: tuple[Path, ...] = (), block: int = 20) -> dict[str, float]:
    """Seconds each reader takes over `clips`: the sum over blocks of `block` clips of the
    fastest of `repeats` reads of that block, the readers taking turns block by block
    (rotating who goes first), so load from other jobs on a shared machine hits them alike.
    Blocks, not single clips: a reader that reads a clip right after another one finds its
    bytes in the CPU cache, which a block of 20 clips (~100 MB) flushes. With `cold` paths,
    their page caches are dropped before every clip (outside the timing)."""
    names = list(readers)
    chunks = [clips[i:i + block] for i in range(0, len(clips), block)]
    best = {n: [float("inf")] * len(chunks) for n in names}
    for r in range(repeats):
        for c, part in enumerate(chunks):
            shift = (c + r) % len(names)
            for name in names[shift:] + names[:shift]:
                total = 0.0
                for frames in part:
                    if cold:
                        drop_page_cache(*cold)
                    t0 = time.perf_counter()
                    readers[name](frames)
                    total += time.perf_counter() - t0
                best[name][c] = min(best[name][c], total)
    return {n: sum(v) for n, v in best.items()}
