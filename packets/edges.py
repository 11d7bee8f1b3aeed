"""LiDAR edge points and their alignment score with image edges (pure math, no I/O).

The method of Levinson & Thrun (2013, "Automatic online calibration of cameras and lasers"):
LiDAR points at depth discontinuities (the near side of a jump, where an object's silhouette
is) should project onto image edges. A candidate extrinsic rotation error r (rotation
vector, rad, about the camera's optical axes: x right, y down, z forward) turns the camera
that took the image: its true pose is T_world_cam exp([r]), so a point p of the recorded
(nominal) camera frame is seen at p' = exp([r])^T p. The alignment score of r is the
weighted mean, over the edge points of many views, of the image's edge strength at the
projection of p' (a smoothed gradient-magnitude map, `pipeline.analysis.edge_align.edge_map`,
read bilinearly). Because an edge point's projection moves by about f * angle pixels for a
rotation by that angle, and the score is averaged over thousands of edge points in views of
different poses, the rotation that maximises it is resolved well below a pixel
(`pipeline.analysis.edge_align.align_rotation` searches it).

Conventions follow `packets.reprojection`: OpenCV pinhole K (pixels), pixel centres at
integer coordinates; every array is float64.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from packets.projection import bilinear, in_image, pinhole
from packets.rigid import apply_T, rotvec_matrix

F64 = npt.NDArray[np.float64]

MIN_DEPTH_M = 0.3
"""Points at or nearer than this depth (m) in the camera are left out."""


def scan_candidates(key: F64, along: int) -> npt.NDArray[np.int64]:
    """Index (N, k) of each point's k = min(6, N) nearest points (itself first) in its scan
    coordinates `key` (N, 2) rad once the axis other than `along` is scaled up 20 times: the
    candidates `scan_neighbours` chooses from (a cKDTree query, the costly part: built once
    per sweep and axis, `scan_edges_and_step` shares the ring axis's)."""
    scaled = key.copy()
    scaled[:, 1 - along] *= 20.0
    k = min(6, len(key))
    _, nb = cKDTree(scaled).query(scaled, k=k)
    out: npt.NDArray[np.int64] = np.asarray(nb, np.int64).reshape(len(key), k)
    return out


def scan_neighbours(key: F64, along: int, max_gap: float,
                    candidates: npt.NDArray[np.int64] | None = None) -> npt.NDArray[np.int64]:
    """Index (N,) of each point's next scan neighbour along axis `along` of its scan
    coordinates `key` (N, 2) rad (azimuth, elevation): the nearest point with a larger
    coordinate on that axis once the other axis is scaled up 20 times (so a ring's neighbour is
    on the same ring, a column's on the same column), -1 where none lies within `max_gap`.
    `candidates`: `scan_candidates(key, along)` when the caller has them."""
    nb = scan_candidates(key, along) if candidates is None else candidates
    d = key[nb, along] - key[:, None, along]
    off = np.abs(key[nb, 1 - along] - key[:, None, 1 - along])
    ahead = np.where((d > 0) & (d <= max_gap) & (off <= max_gap / 2), d, np.inf)
    best = ahead.argmin(1)
    rows = np.arange(len(key))
    out: npt.NDArray[np.int64] = np.where(np.isfinite(ahead[rows, best]), nb[rows, best], -1)
    return out


def _steps(values: F64, nxt: npt.NDArray[np.int64]) -> F64:
    """Per point i with a next neighbour j (N,): how much the step values[j] - values[i]
    stands out from the steps just before i and just after j (the smaller difference; a
    surface changing smoothly, as the ground's range at grazing angles, steps alike), 0 where
    a neighbour is missing."""
    n = len(values)
    prv = np.full(n, -1)
    has = nxt >= 0
    prv[nxt[has]] = np.flatnonzero(has)
    out = np.zeros(n)
    i = np.flatnonzero(has)
    j = nxt[i]
    k, l = prv[i], nxt[j]
    ok = (k >= 0) & (l >= 0)
    i, j, k, l = i[ok], j[ok], k[ok], l[ok]
    step = values[j] - values[i]
    out[i] = np.minimum(np.abs(step - (values[i] - values[k])),
                        np.abs(step - (values[l] - values[j])))
    return out


@dataclass(frozen=True)
class ScanEdges:
    """Edge points of a sweep in the LiDAR frame: points (M, 3) m, weights (M,) in (0, 1],
    and across (M, 3) the unit direction from one neighbour to the other (across the edge)."""

    points: F64
    weights: F64
    across: F64


def scan_edges(xyz_lidar: npt.ArrayLike, intensity: npt.ArrayLike | None = None,
               min_jump: float = 0.1, min_contrast: float = 0.1,
               max_gap_rad: float = np.radians(3.0)) -> ScanEdges:
    """Edge points of a spinning LiDAR's sweep (N, 3) m in its own frame (scan lines are rings
    of about constant elevation about its z axis), between scan neighbours (`scan_neighbours`,
    along rings and across them) where the log range steps by >= `min_jump` (a depth edge:
    weight sqrt(step) capped at 1, Levinson & Thrun's gamma = 0.5) or the intensity steps by >=
    `min_contrast` of its 95th percentile (a material edge, weight likewise), each step
    measured against its neighbouring steps (`_steps`). An edge's point lies on the angular
    midpoint of the two neighbours (the boundary lies anywhere between them: the midpoint is
    unbiased) at the nearer range (a silhouette belongs to the nearer surface)."""
    return _scan_edges(xyz_lidar, intensity, min_jump, min_contrast, max_gap_rad)[0]


def scan_edges_and_step(xyz_lidar: npt.ArrayLike, intensity: npt.ArrayLike | None = None,
                        step_gap_rad: float = np.radians(20.0)) -> tuple[ScanEdges, float]:
    """`scan_edges` of a sweep (default thresholds) and its angular step along the rings
    (rad): the median azimuth gap from each point to its next neighbour on its ring
    (`scan_neighbours` within `step_gap_rad`), 0 for a sweep of fewer than 5 points or
    without one; the ring candidates' query is shared by both."""
    edges, key, ring = _scan_edges(xyz_lidar, intensity)
    if key is None or ring is None:
        return edges, 0.0
    return edges, ring_step(key, ring, step_gap_rad)


def ring_step(key: F64, ring: npt.NDArray[np.int64], max_gap_rad: float) -> float:
    """The median azimuth gap (rad) from each point of scan coordinates `key` (N, 2) rad to
    its next neighbour on its ring (`scan_neighbours` along azimuth within `max_gap_rad`, of
    the candidates `ring` = `scan_candidates(key, 0)`); 0 without one."""
    nxt = scan_neighbours(key, 0, max_gap_rad, ring)
    has = nxt >= 0
    return float(np.median(key[nxt[has], 0] - key[has, 0])) if has.any() else 0.0


def _scan_edges(xyz_lidar: npt.ArrayLike, intensity: npt.ArrayLike | None = None,
                min_jump: float = 0.1, min_contrast: float = 0.1,
                max_gap_rad: float = np.radians(3.0),
                ) -> tuple[ScanEdges, F64 | None, npt.NDArray[np.int64] | None]:
    """`scan_edges`, with the scan coordinates (N', 2) rad of the sweep's finite non-zero
    points and their ring candidates (`scan_candidates(key, 0)`; both None under 5 points)."""
    xyz = np.asarray(xyz_lidar, np.float64)
    r = np.linalg.norm(xyz, axis=1)
    ok = np.flatnonzero(np.isfinite(r) & (r > 0))
    empty = ScanEdges(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    if ok.size < 5:
        return empty, None, None
    p, rr = xyz[ok], r[ok]
    unit = p / rr[:, None]
    key = np.stack([np.arctan2(p[:, 1], p[:, 0]), np.arcsin(np.clip(unit[:, 2], -1, 1))], 1)
    log_r = np.log(rr)
    inten = None
    if intensity is not None:
        iv = np.asarray(intensity, np.float64)[ok]
        scale = float(np.percentile(iv, 95)) if iv.size else 0.0
        inten = iv / scale if scale > 0 else None
    pts, wts, acr = [], [], []
    ring = scan_candidates(key, 0)
    for along in (0, 1):
        nxt = scan_neighbours(key, along, max_gap_rad, ring if along == 0 else None)
        jump = _steps(log_r, nxt)
        w = np.sqrt(np.minimum(np.where(jump >= min_jump, jump, 0.0), 1.0))
        if inten is not None:
            c = _steps(inten, nxt)
            w = np.maximum(w, np.sqrt(np.minimum(np.where(c >= min_contrast, c, 0.0), 1.0)))
        i = np.flatnonzero(w > 0)
        j = nxt[i]
        mid = unit[i] + unit[j]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        pts.append(mid * np.minimum(rr[i], rr[j])[:, None])
        wts.append(w[i])
        d = unit[j] - unit[i]
        acr.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    if not sum(len(w) for w in wts):
        return empty, key, ring
    return ScanEdges(np.concatenate(pts), np.concatenate(wts), np.concatenate(acr)), key, ring


@dataclass(frozen=True)
class EdgeView:
    """One view's edge points and image: points (N, 3) m in the recorded camera frame, their
    weights (N,) > 0, normals (N, 2) the unit image direction across each edge (|u|, |v|
    components used), K (3, 3), and the image's grey levels (h, w)."""

    points: F64
    weights: F64
    normals: F64
    K: F64
    grey: F64


def camera_edges(edges: ScanEdges, T_cam_lidar: F64, K: F64, grey: F64,
                 margin_px: float = 2.0) -> EdgeView:
    """A sweep's edge points seen by one view: moved into the camera frame by T_cam_lidar
    (4, 4) (the recorded extrinsic and the motion between sweep and image), kept where they
    project at least `margin_px` inside the (h, w) image `grey` and in front of the camera,
    with each edge's image normal (the projected `across` direction)."""
    R = T_cam_lidar[:3, :3]
    pc = apply_T(edges.points, T_cam_lidar)
    uv, z = pinhole(pc, K)
    h, w = grey.shape
    keep = (z > MIN_DEPTH_M) & np.isfinite(uv).all(1) & in_image(uv, (h, w), margin_px)
    pc, uv, z = pc[keep], uv[keep], z[keep]
    uv2, _ = pinhole(pc + 0.01 * z[:, None] * (edges.across[keep] @ R.T), K)
    nrm = uv2 - uv
    norm = np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.divide(nrm, norm, out=np.zeros_like(nrm), where=norm > 0)
    return EdgeView(pc, edges.weights[keep], nrm, K, np.asarray(grey, np.float64))


def visible(points_cam: F64, K: F64, hw: tuple[int, int]) -> tuple[F64, npt.NDArray[np.bool_]]:
    """Pixels uv (N, 2) of camera-frame points (N, 3) m and whether each lies in the (h, w)
    image and further than `MIN_DEPTH_M` in front of the camera."""
    uv, z = pinhole(points_cam, K)
    inside: npt.NDArray[np.bool_] = (z > MIN_DEPTH_M) & in_image(uv, hw)
    return uv, inside


def edge_sums(v: EdgeView, points_cam: F64, maps: F64) -> tuple[F64, float]:
    """The weighted edge strength of edge points `points_cam` (N, 3) m (the camera frame;
    `v`'s weights, normals and K) on each of the edge maps stacked (h, w, m, 2): its sum (m,)
    over the points (a map's u and v strength at the point's pixel, read bilinearly, times the
    normal's |u|, |v|; a point leaving the image (`visible`) adds 0) and the sum of the
    weights (the denominator of the mean)."""
    h, w, m = maps.shape[:3]
    den = float(np.sum(v.weights))
    uv, inside = visible(points_cam, v.K, (h, w))
    if den <= 0 or not inside.any():
        return np.zeros(m), den
    vals = bilinear(maps.reshape(h, w, m * 2), uv[inside]).reshape(-1, m, 2)  # (N, m, 2)
    per = np.einsum("nmk,nk->nm", vals, np.abs(v.normals[inside]))
    num: F64 = v.weights[inside] @ per
    return num, den


def alignment_score(views: Sequence[EdgeView], maps: Sequence[F64],
                    r_rad: Sequence[float] | F64) -> float:
    """Weighted mean edge strength (maps, one (h, w, 2) per view) at the projections of every
    view's edge points turned by r (3,) rad (`edge_sums`); NaN without weights."""
    R = rotvec_matrix(r_rad)
    num = den = 0.0
    for v, m in zip(views, maps, strict=True):
        n, d = edge_sums(v, v.points @ R, m.reshape(m.shape[0], m.shape[1], 1, 2))
        num += float(n[0])
        den += d
    return num / den if den > 0 else float("nan")
