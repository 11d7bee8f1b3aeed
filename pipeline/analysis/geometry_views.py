"""Building and scoring the geometry check's views (`pipeline.analysis.geometry_check` runs the
stage): a camera's raw views, its edge views under the recorded geometry and the verdict of
one camera (`judge_camera`); the types and the score they use are in
`pipeline.analysis.geometry_scoring` (below this module and `geometry_overlap`).

Per camera: up to `geometry.views` accepted views (selection status ok, valid in the cache, at
least `MARGIN_S` inside the odometry), those of as many sweeps spread evenly over the
recording (`shared_choice`: the cameras share them); the sweeps are decoded once
(`iter_sweeps`) and their edge points found once (`packets.edges.scan_edges`). Each view's
edge points are moved into its camera by the recorded chain at the image time on the odometry
clock (as `m3gd align --consistency` does, `pipeline.analysis.align_lidar`) and scored against
every view's edge map (blur: `SIGMA_FRACTION` of the image width, at least half the LiDAR's
azimuth step): the score matrix of the shuffled-pairs null. Null pairs are views at least
`MIN_GAP` apart whose edge maps correlate below `MAX_ALIKE` (a static robot sees one image over
and over). A view whose image has a mean Sobel gradient below `FLAT_GRADIENT` grey levels has
no edges (textureless) and is left out.

Every camera is also scored at a small search of its geometry (what its own data allow, and the
likely cause of a low score): the best score over extrinsic rotations about each optical axis
(`ROTATIONS_DEG`, those of at least `MIN_STEPS` LiDAR azimuth steps), translations along the
optical x and y axes (`TRANSLATIONS_M`) and camera clock offsets (`OFFSETS_S`), each read
against the nominal null; and its views are read across each other where they overlap
(`pipeline.analysis.geometry_overlap`: a wrong pose source shows there).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from packets.edge_batch import EdgeBatch, camera_edges_many, own_scores
from packets.edges import (
    EdgeView,
    ScanEdges,
    ring_step,
    scan_candidates,
    scan_edges,
    scan_edges_and_step,
)
from packets.geometry_verdict import (
    Evidence,
    NullTest,
    Search,
    Verdict,
    decide,
    null_rows,
    null_test,
)
from packets.null_stats import z_score
from packets.rigid import rotvec_matrix
from packets.scan_resolution import scan_resolution_deg
from packets.view_overlap import CrossView
from pipeline.analysis.align_lidar import body_track, image_time_ns
from pipeline.analysis.edge_align import edge_map
from pipeline.analysis.geometry_overlap import cross_check
from pipeline.analysis.geometry_scoring import (  # the three types re-exported for callers
    CameraSet as CameraSet,
)
from pipeline.analysis.geometry_scoring import (
    Poses as Poses,
)
from pipeline.analysis.geometry_scoring import (
    RawView as RawView,
)
from pipeline.analysis.geometry_scoring import (
    score_matrix,
)
from pipeline.ingest.sources.sweep_reader import iter_sweeps
from pipeline.stages.common import index_path, run_groups
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.recording_index import SELECTION, SELECTION_FILE, SWEEPS, read_index_table
from store.cache_io import read_views

F64 = npt.NDArray[np.float64]

MARGIN_S = 0.25
"""Views at least this far (s) inside the odometry: the clock-offset search reads poses there."""
OFFSETS_S = (-0.2, -0.1, -0.05, 0.05, 0.1, 0.2)
"""Camera clock offsets (s) the cause search tries."""
TRANSLATIONS_M = (-0.1, 0.1)
"""Extrinsic translations (m) along the optical x and y axes the cause search tries (20 cm too
found a 15 % higher score on a clean synthetic forest camera, 2026-11-28: foliage fits many
placements; 10 cm did not)."""
ROTATIONS_DEG = (-8.0, -5.0, -3.0, -2.0, 2.0, 3.0, 5.0, 8.0)
"""Extrinsic rotations (deg) about each optical axis the cause search tries (those of at least
`MIN_STEPS` LiDAR azimuth steps: an edge is placed to within half a step). 2 deg since a
rendered 2 deg yaw read `ok` on a 192 px camera (its best candidate, 3 deg, scored no higher);
with it the bench's 7 faults are all detected and its clean cameras stay `ok` (2026-11-28)."""
MIN_STEPS = 1.5
SIGMA_FRACTION = 1 / 160
"""Edge-map blur as a share of the image width (1 px at 160 px wide), at least half the LiDAR's
azimuth step in pixels (f x step / 2)."""
MIN_GAP = 2
"""Null pairs are at least this many scored views apart."""
MAX_ALIKE = 0.8
"""Null pairs' edge maps correlate below this."""
NULL_MIN_PAIRS = 3
"""A view enters the null test with at least this many null pairs."""
FLAT_GRADIENT = 0.5
"""A view whose mean Sobel gradient magnitude (grey levels per pixel) is below this is flat."""


def usable_rows(sel: pa.Table, camera: str, valid: npt.NDArray[np.bool_],
                body: Poses) -> list[dict[str, Any]]:
    """The selection rows of `camera` that can be scored, in time order: status ok, valid in
    the cache, at least MARGIN_S inside the odometry."""
    rows = sel.filter(pc.and_(pc.equal(sel["camera"], camera),
                              pc.equal(sel["status"], "ok"))).to_pylist()
    margin = round(MARGIN_S * 1e9)
    t = body.track.t
    rows = [r for r in rows if 0 <= r["frame"] < len(valid) and valid[r["frame"]]
            and t[0] + margin <= image_time_ns(r) <= t[-1] - margin]
    rows.sort(key=lambda r: int(r["stamp_ns"]))
    return rows


def spread(items: list[Any], n: int) -> list[Any]:
    """At most `n` of `items`, spread evenly (the first and last kept)."""
    if len(items) <= n:
        return list(items)
    return [items[k] for k in np.unique(np.linspace(0, len(items) - 1, n).round().astype(int))]


Rows = list[dict[str, Any]]


def shared_choice(usable: dict[str, Rows], n: int) -> dict[str, Rows]:
    """Each camera's scored rows: those of `n` sweeps spread over every camera's usable sweeps
    (one row per sweep), so the cameras share the sweeps decoded; a camera left with fewer than
    half of what it could have takes its own `n` rows spread over its recording."""
    picked = set(spread(sorted({int(r["sweep"]) for rows in usable.values() for r in rows}), n))
    out = {}
    for cam, rows in usable.items():
        first: dict[int, dict[str, Any]] = {}
        for r in rows:
            if int(r["sweep"]) in picked:
                first.setdefault(int(r["sweep"]), r)
        mine = sorted(first.values(), key=lambda r: int(r["stamp_ns"]))
        out[cam] = mine if 2 * len(mine) >= min(n, len(rows)) else spread(rows, n)
    return out


def mean_gradient(grey: F64) -> float:
    """Mean Sobel gradient magnitude (grey levels per pixel; the 3x3 Sobel divided by 8)."""
    gx = cv2.Sobel(grey, cv2.CV_64F, 1, 0, ksize=3) / 8
    gy = cv2.Sobel(grey, cv2.CV_64F, 0, 1, ksize=3) / 8
    return float(np.hypot(gx, gy).mean())


def azimuth_step(xyz: npt.ArrayLike) -> float:
    """The LiDAR's angular step along its rings (rad): the median azimuth gap to each point's
    next neighbour on its ring (`packets.edges.scan_neighbours`, within 20 deg); 0 for a
    sweep of fewer than 5 points."""
    p = np.asarray(xyz, np.float64)
    r = np.linalg.norm(p, axis=1)
    p = p[np.isfinite(r) & (r > 0)]
    if len(p) < 5:
        return 0.0
    unit = p / np.linalg.norm(p, axis=1, keepdims=True)
    key = np.stack([np.arctan2(p[:, 1], p[:, 0]), np.arcsin(np.clip(unit[:, 2], -1, 1))], 1)
    return ring_step(key, scan_candidates(key, 0), np.radians(20.0))


def camera_sets(cfg: M3GDConfig, rec: str, mission: Path,
                body: Poses | None = None) -> list[CameraSet]:
    """The raw views of every camera group of `rec` (sweeps decoded once for all cameras);
    `body`: its odometry when the caller has read it already."""
    idx = index_path(cfg, rec)
    body = body or Poses.of(body_track(idx))
    sel = read_index_table(idx / SELECTION_FILE, SELECTION)
    sweeps = {r["sweep"]: r for r in read_index_table(idx / "sweeps.parquet",
                                                     SWEEPS).to_pylist()}
    usable = {}
    for r, cam, attrs in run_groups(cfg):
        if r == rec:
            valid = read_views(cfg.layout.cache / rec / cam / "valid",
                               list(range(attrs.n_views))).astype(bool)
            usable[cam] = usable_rows(sel, cam, valid, body)
    chosen: dict[str, tuple[list[dict[str, Any]], np.ndarray]] = {}
    for cam, rows in shared_choice(usable, cfg.geometry.views).items():
        images = read_views(cfg.layout.cache / rec / cam / "images",
                            [int(x["frame"]) for x in rows]) if rows else np.zeros((0, 1, 1, 3))
        chosen[cam] = (rows, images)
    need = sorted({int(x["sweep"]) for rows, _ in chosen.values() for x in rows})
    edges: dict[int, ScanEdges] = {}
    step = resolution = 0.0
    for s, sw in zip(need, iter_sweeps(mission, [sweeps[s] for s in need]), strict=True):
        if not step:  # the first sweep's (`azimuth_step`, its ring query shared with the edges')
            edges[s], step = scan_edges_and_step(sw.xyz, sw.intensity)
            resolution = scan_resolution_deg(float(np.degrees(step)), sw.xyz)
        else:
            edges[s] = scan_edges(sw.xyz, sw.intensity)
    return [_camera_set(cam, rows, images, edges, sweeps, body, (step, resolution))
            for cam, (rows, images) in chosen.items()]


def _camera_set(cam: str, rows: list[dict[str, Any]], images: np.ndarray,
                edges: dict[int, ScanEdges], sweeps: dict[int, dict[str, Any]],
                body: Poses, steps: tuple[float, float]) -> CameraSet:
    """A camera's RawViews from its chosen rows, images and the decoded edges; `steps` the
    LiDAR's azimuth step (rad) and the sweep's angular resolution (deg)."""
    greys, flat = [], 0
    for r, img in zip(rows, images, strict=True):
        grey = img.astype(np.float64).mean(axis=-1)
        if mean_gradient(grey) < FLAT_GRADIENT:
            flat += 1
            continue
        greys.append((r, grey))
    poses = _lidar_poses(body, [r for r, _ in greys], sweeps)
    views = []
    for (r, grey), T_lidar in zip(greys, poses, strict=True):
        e = edges[int(r["sweep"])]
        if T_lidar is None or not len(e.points):
            continue
        views.append(RawView(e, T_lidar, image_time_ns(r),
                             np.reshape(np.asarray(r["K_out"], np.float64), (3, 3)), grey,
                             int(r["sweep_stamp_ns"])))
    return CameraSet(cam, views, len(rows), flat, *steps)


def _lidar_poses(body: Poses, rows: list[dict[str, Any]],
                 sweeps: dict[int, dict[str, Any]]) -> list[F64 | None]:
    """T_odom_lidar (4, 4) of each row's LiDAR at its sweep stamp (None outside the odometry),
    read for each LiDAR's rows at once (`Poses.sensors_at`: bit for bit `sensor_at`'s)."""
    lidar = [str(sweeps[r["sweep"]]["lidar"]) for r in rows]
    out: list[F64 | None] = [None] * len(rows)
    for name in dict.fromkeys(lidar):
        at = [k for k, x in enumerate(lidar) if x == name]
        for k, T in zip(at, body.sensors_at(name, [rows[k]["sweep_stamp_ns"] for k in at]),
                        strict=True):
            out[k] = T
    return out


def edge_views(cs: CameraSet, body: Poses, offset_s: float = 0.0) -> list[EdgeView]:
    """The camera's edge views with its clock offset by `offset_s` (image time less it); a
    view without edge points in its image is kept with none (its row scores 0)."""
    stamps = [v.image_ns - offset_s * 1e9 for v in cs.views]
    T = []
    for v, T_cam in zip(cs.views, body.sensors_at(cs.camera, stamps), strict=True):
        if T_cam is None:
            raise DataError(f"camera {cs.camera}: image time {v.image_ns} outside the odometry")
        T.append(np.asarray(np.linalg.solve(T_cam, v.T_odom_lidar), np.float64))
    return camera_edges_many([v.edges for v in cs.views], T, [v.K for v in cs.views],
                             [v.grey for v in cs.views])


def null_pairs(maps: F64) -> npt.NDArray[np.bool_]:
    """allowed (n, n) of maps stacked (h, w, n, 2): views at least MIN_GAP apart whose edge
    maps correlate below MAX_ALIKE."""
    n = maps.shape[2]
    flat = np.moveaxis(maps.sum(-1), 2, 0).reshape(n, -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.corrcoef(flat) if n > 1 else np.ones((n, n))
    corr = np.nan_to_num(np.atleast_2d(corr), nan=1.0)
    gap = np.abs(np.arange(n)[:, None] - np.arange(n)[None, :]) >= MIN_GAP
    out: npt.NDArray[np.bool_] = gap & (corr < MAX_ALIKE)
    return out


@dataclass(frozen=True)
class CameraResult:
    """One camera's verdict, its null test (None without one), evidence, cause search, time
    (s) and cross-view consistency (None without a null test)."""

    camera: str
    verdict: Verdict
    test: NullTest | None
    evidence: Evidence
    best: Search | None
    seconds: float
    cross: CrossView | None = None


def judge_camera(cs: CameraSet, body: Poses) -> CameraResult:
    """The verdict of one camera's raw views (module docstring)."""
    t0 = time.perf_counter()
    views = edge_views(cs, body)
    scored = [k for k, v in enumerate(views) if len(v.points)]
    views = [views[k] for k in scored]
    points = int(sum(len(v.points) for v in views))
    if not views:
        ev = Evidence(0, 0, cs.flat)
        return CameraResult(cs.camera, decide(None, ev), None, ev, None,
                            time.perf_counter() - t0)
    f_px = float(views[0].K[0, 0])
    sigma = max(1.0, SIGMA_FRACTION * views[0].grey.shape[1], 0.5 * f_px * cs.step_rad)
    maps = np.stack([edge_map(v.grey, sigma) for v in views], axis=2)  # (h, w, n, 2)
    allowed = null_pairs(maps)
    test = null_test(score_matrix(views, maps), allowed, NULL_MIN_PAIRS)
    alike = "" if test is not None else (
        f"the {len(views)} views' images are alike (a static robot or scene?): no pair of "
        "different images for the null")
    ev = Evidence(len(views), points, cs.flat, alike,
                  max(float(np.degrees(cs.step_rad)), cs.resolution_deg))
    best = cross = None
    if test is not None:  # what a turned or shifted geometry reaches; the views' agreement
        batch = EdgeBatch.of(views)
        best = _search(cs, body, scored, batch, maps, null_rows(allowed, NULL_MIN_PAIRS), test)
        cross = cross_check(cs, body, scored, maps, own_scores(batch, batch.points, maps),
                            [len(v.points) for v in views], test)
    return CameraResult(cs.camera, decide(test, ev, best, cross=cross), test, ev, best,
                        time.perf_counter() - t0, cross)


def _search(cs: CameraSet, body: Poses, scored: list[int], batch: EdgeBatch, maps: F64,
            rows: npt.NDArray[np.int64], test: NullTest) -> Search | None:
    """The best mean own-image score over `rows` of a rotation about one optical axis, a
    translation along the optical x or y axis or a clock offset; its z against the nominal
    null (`test`: a turned or shifted geometry meets unrelated images as the nominal one
    does). `batch`: the nominal edge views of `scored` (indices into `cs.views`), scored
    together (`packets.edge_batch`: each view's score as `diagonal` gives it, bit for bit) and
    built once for every rotation and translation."""
    cands: list[tuple[float, str]] = []
    least = np.degrees(MIN_STEPS * cs.step_rad)
    for axis, name in enumerate(("pitch", "yaw", "roll")):
        for deg in [d for d in ROTATIONS_DEG if abs(d) >= least]:
            r = np.zeros(3)
            r[axis] = np.radians(deg)
            pts = batch.rotated(rotvec_matrix(r))
            cands.append((float(own_scores(batch, pts, maps)[rows].mean()),
                          f"extrinsic rotation ({name} {deg:+.0f} deg)"))
    for axis, name in enumerate("xy"):
        for m in TRANSLATIONS_M:
            pts = batch.shifted(np.eye(3)[axis] * m)
            cands.append((float(own_scores(batch, pts, maps)[rows].mean()),
                          f"extrinsic translation ({name} {m * 100:+.0f} cm)"))
    for off in OFFSETS_S:
        shifted = edge_views(cs, body, off)
        moved = EdgeBatch.of([shifted[k] for k in scored])
        cands.append((float(own_scores(moved, moved.points, maps)[rows].mean()),
                      f"clock offset ({off * 1e3:+.0f} ms)"))
    score, moved_by = max(cands, key=lambda c: c[0])
    return Search(score, z_score(score, test.null_mean, test.null_std), moved_by)
