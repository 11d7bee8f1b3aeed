"""LiDAR scans of a Hugging Face store: padded `points` (N, maxP, 3) sliced by `valid` (N, 1).

Read one chunk of scans at a time (never the whole array), and only the valid prefix of each
chunk. The same drop rules as the bag reader (`pipeline.ingest.sources.pointcloud`): invalid returns
(NaN/Inf) and all-zero points are dropped and counted by kind; a point farther than MAX_COORD_M
is corrupt. The release has no
per-point time: every point carries the scan's stamp.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from pipeline.ingest.sources.hf.store import DATA_DIR, DECODE_ERRORS, HfStore, seconds_to_ns
from pipeline.ingest.sources.pointcloud import PointCounts, Sweep, point_kinds
from schemas.errors import DataError, MissingDataError

F32 = npt.NDArray[np.float32]
XYZ = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


class BadScan(NamedTuple):
    """A scan that cannot be read: what is wrong, naming file, array and row; for a chunk that
    cannot be read at all, its first and last row."""

    detail: str
    chunk: tuple[int, int] | None = None


class ScanBlock(NamedTuple):
    """One chunk of scans: first row, valid counts (k,), points (k, <=maxP, 3), intensity."""

    start: int
    valid: npt.NDArray[np.int64]
    points: F32
    intensity: F32


def keep_mask(xyz: F32) -> tuple[PointCounts, npt.NDArray[np.bool_]]:
    """Counts and the kept-points mask of one scan's valid points (n, 3) float32."""
    cloud = np.ascontiguousarray(xyz, dtype=np.float32).view(XYZ)[:, 0]
    kinds = point_kinds(cloud["x"], cloud["y"], cloud["z"])
    return kinds.counts(), kinds.keep


class ScanReader:
    """Reads the scans of one LiDAR group in chunk-sized blocks; the last block is kept."""

    def __init__(self, store: HfStore, group: str) -> None:
        """Bind the `points`, `valid`, `intensity` and `timestamp` arrays; check their shapes."""
        self.store, self.group = store, group
        self.points = store.array(group, "points")
        self.valid = store.array(group, "valid")
        try:
            self.intensity: Any = store.array(group, "intensity")
        except DataError:  # optional: zeros without it
            self.intensity = None
        self.n = int(store.array(group, "timestamp").shape[0])
        if self.points.ndim != 3 or self.points.shape[2] != 3:
            raise DataError(f"{store.where(group, 'points')}: shape {self.points.shape}, "
                             "expected (N, maxP, 3)")  # fmt: skip
        for name, arr in (("points", self.points), ("valid", self.valid)):
            if arr.shape[0] != self.n:
                raise DataError(f"{store.where(group, name)}: {arr.shape[0]} rows but "
                                 f"{store.where(group, 'timestamp')} has {self.n}")  # fmt: skip
        self.max_p = int(self.points.shape[1])
        self.step = int(self.points.chunks[0])
        self._block: ScanBlock | None = None

    def block(self, row: int) -> ScanBlock | BadScan:
        """The chunk of scans holding `row` (the valid prefix of each), or why it is unreadable."""
        b = self._block
        if b is not None and b.start <= row < b.start + b.valid.size:
            return b
        start = row - row % self.step
        stop = min(self.n, start + self.step)
        try:
            valid = np.asarray(self.valid[start:stop], np.int64).reshape(stop - start, -1)[:, 0]
            width = int(np.clip(valid, 0, self.max_p).max(initial=0))
            pts = np.asarray(self.points[start:stop, :width], dtype=np.float32)
            inten = (np.asarray(self.intensity[start:stop, :width], dtype=np.float32)
                     if self.intensity is not None else np.zeros(pts.shape[:2], np.float32))
        except DECODE_ERRORS as err:  # a damaged chunk: its check, its decoder, I/O
            return BadScan(f"{self.store.where(self.group, 'points')} rows {start}..{stop - 1} "
                           f"(one chunk) cannot be read: {type(err).__name__}: {err}",
                           (start, stop - 1))  # fmt: skip
        self._block = ScanBlock(start, valid, pts, inten)
        return self._block

    def scan(self, row: int) -> tuple[F32, F32] | BadScan:
        """(xyz (v, 3), intensity (v,)) of the valid points of scan `row`, or what is wrong."""
        b = self.block(row)
        if isinstance(b, BadScan):
            return b
        v = int(b.valid[row - b.start])
        if not 0 <= v <= self.max_p:
            return BadScan(f"{self.store.where(self.group, 'valid')} row {row}: valid = {v} is "
                           f"outside 0..maxP = {self.max_p} of "
                           f"{self.store.where(self.group, 'points')}")  # fmt: skip
        return b.points[row - b.start, :v], b.intensity[row - b.start, :v]

    def rows(self) -> Iterator[tuple[int, tuple[F32, F32] | BadScan]]:
        """Every scan in row order, one chunk in memory."""
        for row in range(self.n):
            yield row, self.scan(row)


def decode_scan(xyz: F32, intensity: F32, stamp_ns: int) -> Sweep:
    """A Sweep of the kept points; every point stamped with the scan stamp (no per-point time)."""
    counts, keep = keep_mask(xyz)
    inten = np.nan_to_num(intensity[keep], nan=0.0, posinf=0.0, neginf=0.0)
    xyz_kept = np.ascontiguousarray(xyz[keep], dtype=np.float32)
    return Sweep(xyz_kept, inten.astype(np.float32), np.full(counts.valid, stamp_ns, np.int64),
                 counts)  # fmt: skip


_OPEN: dict[tuple[str, str, int], ScanReader] = {}
"""The last scan reader, by (mission, group, inode of the group folder): packets load sweeps one
by one in near row order, so the chunk decoded for one sweep serves the next ones (one chunk is
held). A store written anew at the same path has a new folder, hence a new reader."""


def iter_hf_sweeps(mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
    """Decode indexed sweeps (rows of sweeps.parquet: topic = group, ordinal = row)."""
    for row in rows:
        group = str(row["topic"])
        key = (str(mission_dir.resolve()), group, (mission_dir / DATA_DIR / group).stat().st_ino)
        reader = _OPEN.get(key)
        if reader is None:
            _OPEN.clear()
            reader = _OPEN[key] = ScanReader(HfStore.open(mission_dir), group)
        i = int(row["ordinal"])
        stamps, _ = seconds_to_ns(np.asarray(reader.store.array(group, "timestamp")[i : i + 1]))
        if int(stamps[0]) != int(row["stamp_ns"]):
            raise MissingDataError(f"{reader.store.where(group, 'timestamp')} row {i}: stamp "
                              f"{int(stamps[0])} ns, the index says {row['stamp_ns']} ns")
        got = reader.scan(i)
        if isinstance(got, BadScan):
            raise MissingDataError(got.detail)
        yield decode_scan(got[0], got[1], int(row["stamp_ns"]))
