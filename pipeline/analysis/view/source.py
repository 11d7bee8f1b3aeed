"""What `m3gd view` reads: one recording's cache groups, selection, odometry, rejects and sweeps.

Everything per view is read one shard row at a time (`shard_rows`), so memory follows one shard
of views per camera and one decoded sweep, not the recording's length. Per-recording tables are
read with only the small columns they need.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from pipeline.analysis.view.scene import ViewPlan, in_range
from pipeline.ingest.sources.sweep_reader import iter_sweeps
from pipeline.stages.common import index_path, run_groups
from schemas.cache_layout import GroupAttrs, group_name, shard_regions
from schemas.config import M3GDConfig
from schemas.layout import OutputLayout
from schemas.missions import mission_of, recording_names
from schemas.recording_index import (
    ODOMETRY,
    REJECTS,
    SELECTION,
    SWEEPS,
    ViewStatus,
    read_index_table,
    table_path,
)
from store.cache_io import read_clip

VIEW_ARRAYS = ("images", "stamp_ns", "K", "T_world_cam", "T_cam_lidar")
"""Cache arrays read for every shown view (plus g where the packets stage wrote it)."""
SELECTION_COLUMNS = ["camera", "frame", "stamp_ns", "sweep", "sweep_stamp_ns", "dtau_s",
                     "status", "reason"]


@dataclass(frozen=True)
class CameraSource:
    """One camera group of the recording: cache path, attributes and its selection columns.

    selection: column -> (N,) array indexed by frame (sweep int64, ok bool, reason str, dtau_s
    float64, stamp_ns / sweep_stamp_ns int64).
    """

    camera: str
    path: Path
    attrs: GroupAttrs
    selection: dict[str, np.ndarray]

    @property
    def has_packets(self) -> bool:
        """Whether the packets stage wrote g for this group."""
        return (self.path / "g" / "zarr.json").exists()


@dataclass(frozen=True)
class ViewBatch:
    """The shown views of one camera inside one shard: frames (k,) and arrays (k, ...)."""

    camera: CameraSource
    frames: list[int]
    arrays: dict[str, np.ndarray]


@dataclass(frozen=True)
class RecordingSource:
    """One recording of an output directory, ready to be read view by view."""

    cfg: M3GDConfig
    recording: str
    cameras: dict[str, CameraSource]
    t0_ns: int
    """Stamp of the recording's first image (any camera): the origin of --start / --end."""

    @property
    def index(self) -> Path:
        """The recording's index folder."""
        return index_path(self.cfg, self.recording)

    def stamps(self) -> dict[str, np.ndarray]:
        """camera -> (N,) int64 image stamps by frame."""
        return {c: s.selection["stamp_ns"] for c, s in self.cameras.items()}


def open_recording(cfg: M3GDConfig, recording: str | None,
                   cameras: list[str] | None) -> RecordingSource:
    """The cache groups and selection of `recording` (default: the run's first), optionally a
    subset of its cameras; ValueError naming what is missing."""
    names = recording_names(cfg)
    rec = recording or (names[0] if names else None)
    if rec is None or rec not in names:
        raise ValueError(f"recording {rec!r} is not part of this run; one of {names}")
    groups = {c: a for r, c, a in run_groups(cfg) if r == rec}
    if not groups:
        raise ValueError(f"{OutputLayout(cfg.output_dir).cache / rec}: no cache groups; run the "
                         "pipeline (at least ingest and select) first")
    wanted = list(groups) if cameras is None else cameras
    missing = [c for c in wanted if c not in groups]
    if missing:
        raise ValueError(f"{rec}: no cache group for camera(s) {missing}; one of {list(groups)}")
    sel = read_index_table(table_path(index_path(cfg, rec), "selection"), SELECTION)
    sel = sel.select(SELECTION_COLUMNS)
    out = {}
    for cam in wanted:
        attrs = groups[cam]
        out[cam] = CameraSource(cam, OutputLayout(cfg.output_dir).cache / rec / cam, attrs,
                                _by_frame(sel.filter(pc.equal(sel["camera"], cam)), attrs.n_views,
                                          group_name(rec, cam)))
    t0 = int(pc.min(sel["stamp_ns"]).as_py() or 0)
    return RecordingSource(cfg, rec, out, t0)


def _by_frame(rows: pa.Table, n_views: int, where: str) -> dict[str, np.ndarray]:
    """Selection columns of one camera as frame-indexed arrays; every frame must have a row."""
    frame = rows["frame"].to_numpy()
    if sorted(frame.tolist()) != list(range(n_views)):
        raise ValueError(f"{where}: selection has {frame.size} rows for {n_views} cached views; "
                         "rerun select")
    order = np.argsort(frame)
    col = {n: rows[n].to_numpy(zero_copy_only=False)[order] for n in SELECTION_COLUMNS[2:]}
    col["ok"] = col.pop("status") == ViewStatus.OK.value
    return col


def shard_rows(src: RecordingSource, plan: ViewPlan, with_images: bool = True
               ) -> Iterator[list[ViewBatch]]:
    """The planned views, one shard row at a time (shard k of every camera), read from the cache.

    with_images=False skips the image array (metadata and g only).
    """
    rows = max((len(shard_regions(c.attrs.n_views, c.attrs.shard_views))
                for c in src.cameras.values()), default=0)
    for k in range(rows):
        row = []
        for cam, cs in src.cameras.items():
            regions = shard_regions(cs.attrs.n_views, cs.attrs.shard_views)
            if k >= len(regions):
                continue
            lo, hi = regions[k]
            frames = [int(f) for f in plan.frames.get(cam, ()) if lo <= f < hi]
            if not frames:
                continue
            names = [n for n in VIEW_ARRAYS if with_images or n != "images"]
            names += ["g"] if cs.has_packets else []
            row.append(ViewBatch(cs, frames, read_clip(cs.path, names, frames)))
        if row:
            yield row


class SweepReader:
    """Decodes a recording's sweeps from its bags, a sorted run of them per bag opening."""

    def __init__(self, src: RecordingSource) -> None:
        """Index the recording's sweeps (small columns only)."""
        self.mission = mission_of(src.cfg, src.recording)
        table = read_index_table(table_path(src.index, "sweeps"), SWEEPS)
        keep = ["sweep", "stamp_ns", "file", "topic", "bag_time_ns", "ordinal"]
        self.rows = {r["sweep"]: r for r in table.select(keep).to_pylist()}

    def decode(self, sweeps: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        """(sweep, xyz (N, 3) float32 in the LiDAR frame) of `sweeps`, in sorted order."""
        order = sorted(set(sweeps))
        for s, sw in zip(order, iter_sweeps(self.mission, [self.rows[s] for s in order]),
                         strict=True):
            yield s, sw.xyz


def odometry(src: RecordingSource, start_ns: int | None, end_ns: int | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Odometry samples inside [start_ns, end_ns]: stamps (M,) int64, positions (M, 3) and
    quaternions xyzw (M, 4) float64, the pose of the body in the odometry (world) frame."""
    t = read_index_table(table_path(src.index, "odometry"), ODOMETRY)
    stamps = t["stamp_ns"].to_numpy().astype(np.int64)
    keep = in_range(stamps, start_ns, end_ns)
    pos = np.asarray(t["position"].combine_chunks().flatten().to_numpy(), np.float64)
    quat = np.asarray(t["quat_xyzw"].combine_chunks().flatten().to_numpy(), np.float64)
    return stamps[keep], pos.reshape(-1, 3)[keep], quat.reshape(-1, 4)[keep]


def rejects(src: RecordingSource, start_ns: int | None, end_ns: int | None
            ) -> list[dict[str, Any]]:
    """Rows of the recording's rejects table with stamps inside [start_ns, end_ns]."""
    path = table_path(src.index, "rejects")
    if not path.exists():
        return []
    t = read_index_table(path, REJECTS)
    keep = in_range(t["stamp_ns"].to_numpy().astype(np.int64), start_ns, end_ns)
    rows: list[dict[str, Any]] = t.filter(pa.array(keep)).to_pylist()
    return rows

