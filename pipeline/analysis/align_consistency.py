"""`m3gd align --consistency`: reprojection consistency of every camera of the cache.

Two checks per camera: the clock offset from the photometric consistency of view pairs on
the LiDAR points (below), then the extrinsic rotation from the alignment of LiDAR edge points
with image edges at that offset (`pipeline.analysis.align_lidar`, method `lidar_edges`). View
pairs alone see a rotation shared by all of a camera's views only through parallax; the LiDAR
sees it directly.

Per `<recording>/<camera>` group: the valid views' recorded poses (T_world_cam at stamp_ns)
form the camera's track (`model.reprojection_consistency.Track`); view pairs `gaps` frames
apart (at most `max_pairs`, spread evenly over the recording) are compared where both see the
LiDAR points of the first view (its packet depth lifted with its recorded pose, g channel
`inv_mean_depth`); images are read in grey levels (mean of RGB, 0..255). The sweep
(`model.reprojection_consistency.sweep_offset`) finds the clock offset that minimises the
mean photometric error; one row per group (schema REPROJECTION_CONSISTENCY): the offset, the
rotation (rotation vector about the camera's optical axes) and its method, the pair error at
the recorded calibration (before) and at the estimate (after), the edge alignment score
before and after.

Only views whose stamps lie at least the largest swept offset inside the track are paired, so
every candidate sees the same pairs. A group with no usable pair is reported (skipped), never
written as NaN.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from packets.reprojection import packet_depth
from packets.reprojection_consistency import Pair, Track, lift_cells, objective, sweep_offset
from pipeline.analysis.align import CacheGroup, cache_groups
from pipeline.analysis.align_lidar import METHOD, edge_views, recover_rotation
from pipeline.analysis.edge_align import EdgeEstimate
from pipeline.ingest.sources.staging import staged
from pipeline.stages.common import index_path
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.layout import OutputLayout
from schemas.missions import mission_of
from schemas.tables import REPROJECTION_CONSISTENCY, write_table
from store.cache_io import read_views

CONSISTENCY_FILE = "reprojection_consistency.parquet"


@dataclass(frozen=True)
class SweepGrid:
    """The candidates: clock offsets within +-max_offset_ms (step_ms; `rounds` grids, each
    half as wide about the last minimum), rotations within +-max_rotation_deg about each axis
    (step_deg at the first level of `model.lidar_edges.align_rotation`)."""

    max_offset_ms: float = 60.0
    step_ms: float = 5.0
    max_rotation_deg: float = 1.0
    step_deg: float = 0.1
    rounds: int = 3

    def offsets_s(self) -> np.ndarray:
        n = round(self.max_offset_ms / self.step_ms)
        return np.arange(-n, n + 1) * self.step_ms * 1e-3

    def angles_rad(self) -> np.ndarray:
        n = round(self.max_rotation_deg / self.step_deg)
        out: np.ndarray = np.radians(np.arange(-n, n + 1) * self.step_deg)
        return out

    def angle_steps(self) -> int:
        """Grid points per axis of the rotation search's first level (odd)."""
        return 2 * round(self.max_rotation_deg / self.step_deg) + 1

    def check(self) -> None:
        """Refuse an empty or degenerate grid."""
        if not (0 < self.step_ms <= self.max_offset_ms and 0 < self.step_deg
                <= self.max_rotation_deg and self.rounds >= 1):
            raise DataError(f"sweep grid {self}: steps must be > 0 and <= their ranges, "
                            "rounds >= 1")


@dataclass(frozen=True)
class GroupPairs:
    """One group's pairs and track, or why it has none (`skipped`)."""

    pairs: list[Pair]
    track: Track | None
    skipped: str = ""


def _grey(images: np.ndarray) -> np.ndarray:
    """(k, h, w, 3) uint8 -> (k, h, w, 1) float64 grey levels."""
    out: np.ndarray = images.astype(np.float64).mean(axis=-1, keepdims=True)
    return out


def pair_indices(n: int, gaps: tuple[int, ...], max_pairs: int) -> list[tuple[int, int]]:
    """Pairs (i, i + gap) of n ordered views, at most `max_pairs`, spread evenly (the first
    and last kept) in (i, gap) order."""
    all_pairs = [(i, i + g) for i in range(n) for g in gaps if i + g < n]
    if len(all_pairs) <= max_pairs:
        return all_pairs
    keep = np.unique(np.linspace(0, len(all_pairs) - 1, max_pairs).round().astype(int))
    return [all_pairs[k] for k in keep]


def group_pairs(group: CacheGroup, margin_s: float, gaps: tuple[int, ...],
                max_pairs: int, per_side: int = 4) -> GroupPairs:
    """The pairs and track of one group (module docstring); `margin_s` the largest offset."""
    n = group.attrs.n_views
    frames = list(range(n))
    valid = read_views(group.path / "valid", frames).astype(bool)
    stamps = read_views(group.path / "stamp_ns", frames).astype(np.int64)
    poses = read_views(group.path / "T_world_cam", frames).astype(np.float64)
    Ks = read_views(group.path / "K", frames).astype(np.float64)
    keep: list[int] = np.flatnonzero(valid).tolist()
    keep.sort(key=lambda f: int(stamps[f]))
    keep = [f for k, f in enumerate(keep) if k == 0 or stamps[f] > stamps[keep[k - 1]]]
    if len(keep) < 2:
        return GroupPairs([], None, f"{len(keep)} valid view(s)")
    track = Track(stamps[keep], poses[keep])
    margin = round(margin_s * 1e9)
    inner = [f for f in keep if track.t[0] + margin <= stamps[f] <= track.t[-1] - margin]
    chosen = [(inner[i], inner[j]) for i, j in pair_indices(len(inner), gaps, max_pairs)]
    if not chosen:
        return GroupPairs([], track, f"no view pair {gaps} frames apart inside the track")
    need = sorted({f for p in chosen for f in p})
    images = dict(zip(need, _grey(read_views(group.path / "images", need)), strict=True))
    depth = dict(zip(need, packet_depth(read_views(group.path / "g", need)), strict=True))
    hw = (group.attrs.image_h, group.attrs.image_w)
    pairs = []
    for a, b in chosen:
        pts = lift_cells(depth[a], Ks[a], poses[a], hw, per_side)
        if len(pts):
            pairs.append(Pair(images[a], images[b], Ks[a], Ks[b], int(stamps[a]),
                              int(stamps[b]), pts))
    if not pairs:
        return GroupPairs([], track, "no LiDAR support in the paired views")
    return GroupPairs(pairs, track)


@dataclass(frozen=True)
class GroupEstimate:
    """One group's answer: clock offset (s), pair errors before / after, the edge estimate."""

    offset_s: float
    error_before: float
    error_after: float
    edges: EdgeEstimate
    edge_views: int


def estimate_row(group: CacheGroup, gp: GroupPairs, est: GroupEstimate) -> dict[str, object]:
    """One REPROJECTION_CONSISTENCY row (rotation vector components in degrees)."""
    r = est.edges.rotation_rad
    pitch, yaw, roll = np.degrees(r)  # about x (right), y (down), z (forward)
    return {"recording": group.attrs.recording, "camera": group.attrs.camera,
            "pairs": len(gp.pairs),
            "points": round(float(np.mean([len(p.points) for p in gp.pairs]))),
            "offset_ms": est.offset_s * 1e3, "roll_deg": float(roll),
            "pitch_deg": float(pitch), "yaw_deg": float(yaw),
            "rotation_deg": float(np.degrees(np.linalg.norm(r))),
            "rotation_method": METHOD, "edge_views": est.edge_views,
            "edge_points": est.edges.points, "edge_score_before": est.edges.score_nominal,
            "edge_score_after": est.edges.score_max,
            "error_before": est.error_before, "error_after": est.error_after}


@dataclass(frozen=True)
class ConsistencyResult:
    """The table (one row per group with pairs) and the groups skipped, with why."""

    table: pa.Table
    skipped: dict[str, str]


def estimate_group(cfg: M3GDConfig, group: CacheGroup, gp: GroupPairs, track: Track,
                   grid: SweepGrid, max_views: int) -> GroupEstimate | str:
    """The offset (pairs), then the rotation (LiDAR edges at that offset); or why not."""
    c, before, after = sweep_offset(gp.pairs, track, grid.offsets_s(), grid.rounds)
    if not np.isfinite([before, after]).all():
        return "no pair sees common points at the recorded calibration"
    rec = group.attrs.recording
    with staged(mission_of(cfg, rec)) as mission:
        ev = edge_views(group, index_path(cfg, rec), mission, c, grid.max_offset_ms * 1e-3,
                        max_views)
    edges = recover_rotation(ev, grid.max_rotation_deg, grid.angle_steps())
    if edges is None:
        return f"no LiDAR edge point in any of {ev.tried} view(s)"
    return GroupEstimate(c, before, objective(gp.pairs, track, c, edges.rotation_rad),
                         edges, len(ev.views))


def run_consistency(cfg: M3GDConfig, grid: SweepGrid | None = None,
                    gaps: tuple[int, ...] = (2, 4), max_pairs: int = 24,
                    max_views: int = 64,
                    on_group: Callable[[int], None] | None = None) -> ConsistencyResult:
    """Reprojection consistency of every group of the cache of `cfg.output_dir` (module
    docstring); `max_views` views per camera for the edge alignment."""
    grid = grid or SweepGrid()
    grid.check()
    if not gaps or min(gaps) < 1 or max_pairs < 1 or max_views < 1:
        raise DataError(f"gaps {gaps} must be >= 1, max_pairs {max_pairs} and max_views "
                        f"{max_views} >= 1")
    rows, skipped = [], {}
    for group in cache_groups(cfg.output_dir):
        name = f"{group.attrs.recording}/{group.attrs.camera}"
        gp = group_pairs(group, grid.max_offset_ms * 1e-3, gaps, max_pairs)
        if gp.track is not None and gp.pairs:
            est = estimate_group(cfg, group, gp, gp.track, grid, max_views)
            if isinstance(est, GroupEstimate):
                rows.append(estimate_row(group, gp, est))
            else:
                skipped[name] = est
        else:
            skipped[name] = gp.skipped
        if on_group is not None:
            on_group(1)
    return ConsistencyResult(pa.Table.from_pylist(rows, schema=REPROJECTION_CONSISTENCY),
                             skipped)


def write_consistency(output_dir: Path, table: pa.Table) -> Path:
    """Write the table to `<output_dir>/stats/reprojection_consistency.parquet`; the path."""
    path = OutputLayout(output_dir).stats / CONSISTENCY_FILE
    write_table(table, REPROJECTION_CONSISTENCY, path)
    return path


def summary_lines(result: ConsistencyResult) -> list[str]:
    """A one-screen summary: one line per camera, then the skipped groups."""
    lines = [f"{'recording/camera':<32} {'pairs':>5} {'offset ms':>9} {'roll':>6} "
             f"{'pitch':>6} {'yaw':>6} {'rot deg':>7} {'err before':>10} {'after':>8}"]
    lines += [f"{r['recording'] + '/' + r['camera']:<32} {r['pairs']:>5} "
              f"{r['offset_ms']:>9.1f} {r['roll_deg']:>6.2f} {r['pitch_deg']:>6.2f} "
              f"{r['yaw_deg']:>6.2f} {r['rotation_deg']:>7.2f} "
              f"{r['error_before']:>10.1f} {r['error_after']:>8.1f}"
              for r in result.table.to_pylist()]
    lines += [f"skipped {name}: {why}" for name, why in sorted(result.skipped.items())]
    return lines
