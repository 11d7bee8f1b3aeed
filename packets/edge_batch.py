"""Many edge views, each scored on its own edge map, in one pass (pure math, no I/O).

`own_scores` gives what `packets.edges.edge_sums` gives view by view (each view's edge points
on its own map, over its weights) for every view of an `EdgeBatch` at once: the points of all
views concatenated, projected and read in the stacked maps with one array operation each,
only the final weighted sum (a BLAS product whose rounding depends on its length) taken view
by view on arrays of the view's own length. Each step is the per-view step's arithmetic row
by row, so each score equals the per-view one bit for bit (pinned by a test, on random views
and the geometry check's own). A view of a single point is projected on its own: a (1, 3)
product takes numpy's vector path, which rounds differently from the matrix one.

`EdgeBatch.of` is built once per set of views and reused by every candidate geometry that only
turns (`rotated`) or shifts (`shifted`) the points in the camera frame (the geometry check's
cause search, `pipeline.analysis.geometry_views`).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import numpy.typing as npt

from packets.edges import MIN_DEPTH_M, EdgeView, ScanEdges, camera_edges
from packets.projection import in_image
from packets.rigid import apply_T

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class EdgeBatch:
    """n edge views concatenated: points (P, 3) m (each in its own camera frame), weights
    (P,), |normals| (P, 2), `starts` (n + 1,) each view's first row (and P), K (n, 3, 3) and
    each view's weight sum `den` (n,) (`np.sum` of its weights, as `edge_sums` takes it)."""

    points: F64
    weights: F64
    normals_abs: F64
    starts: I64
    K: F64
    den: F64

    @classmethod
    def of(cls, views: list[EdgeView]) -> EdgeBatch:
        """The batch of `views` (in order)."""
        sizes = [len(v.points) for v in views]
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

        def cat(parts: list[F64], width: int) -> F64:
            out: F64 = (np.concatenate(parts) if parts else np.zeros((0, width)))
            return out

        return cls(cat([np.asarray(v.points, np.float64) for v in views], 3),
                   np.concatenate([v.weights for v in views]) if views else np.zeros(0),
                   np.abs(cat([np.asarray(v.normals, np.float64) for v in views], 2)),
                   starts, np.array([v.K for v in views]).reshape(-1, 3, 3),
                   np.array([float(np.sum(v.weights)) for v in views]))

    @property
    def n(self) -> int:
        """The number of views."""
        return len(self.starts) - 1

    def rotated(self, R: F64) -> F64:
        """Every view's points (P, 3) times R (3, 3) (`points @ R`, as each view's alone)."""
        return rows_product(self.points, np.asarray(R, np.float64), self.starts)

    def shifted(self, d: F64) -> F64:
        """Every view's points (P, 3) less d (3,) m."""
        out: F64 = self.points - d
        return out


def rows_product(points: F64, M: F64, starts: I64) -> F64:
    """points (P, 3) @ M (3, 3) for views at `starts` (n + 1,), each row rounded as the view's
    own product rounds it (a single-point view's product on its own)."""
    out: F64 = points @ M
    for a, b in pairwise(starts):
        if b - a == 1:
            out[a:b] = points[a:b] @ M
    return out


def _pixels(batch: EdgeBatch, points: F64) -> tuple[F64, F64]:
    """uv (P, 2) and z (P,) of every view's points (P, 3) through its K, as
    `packets.projection.pinhole` computes them view by view."""
    z = points[:, 2]
    same = bool(batch.n) and bool((batch.K[0] == batch.K).all())
    if same:
        pix = rows_product(points, batch.K[0].T, batch.starts)
    else:
        pix = np.zeros_like(points)
        for k, (a, b) in enumerate(pairwise(batch.starts)):
            pix[a:b] = points[a:b] @ batch.K[k].T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv: F64 = pix[:, :2] / np.where(z > 0, z, np.nan)[:, None]
    return uv, z


def _bilinear(maps: F64, uv: F64, view: I64) -> F64:
    """maps stacked (h, w, n, 2) read at pixels uv (Q, 2), each in map `view` (Q,) ->
    (Q, 2): `packets.projection.bilinear`'s arithmetic on each view's own map (its four
    neighbours gathered from the maps flattened to (h * w * n, 2))."""
    h, w, n = maps.shape[:3]
    flat = maps.reshape(h * w * n, 2)
    u, v = np.clip(uv[:, 0], 0, w - 1), np.clip(uv[:, 1], 0, h - 1)
    u0 = np.minimum(np.floor(u), max(w - 2, 0)).astype(np.int64)
    v0 = np.minimum(np.floor(v), max(h - 2, 0)).astype(np.int64)
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    r0, r1 = v0 * w, v1 * w
    out: F64 = (flat[(r0 + u0) * n + view] * (1 - fu) * (1 - fv)
                + flat[(r0 + u1) * n + view] * fu * (1 - fv)
                + flat[(r1 + u0) * n + view] * (1 - fu) * fv
                + flat[(r1 + u1) * n + view] * fu * fv)
    return out


def own_scores(batch: EdgeBatch, points: F64, maps: F64, which: I64 | None = None) -> F64:
    """Scores (n,): view i's `points` rows (its edge points in its camera frame, m) on its own
    edge map of maps stacked (h, w, m, 2) (map i, or map `which[i]` with `which` (n,)), over
    its weight sum (0 without weights or without a point in the image):
    `packets.edges.edge_sums` per view, bit for bit."""
    h, w = maps.shape[:2]
    uv, z = _pixels(batch, points)
    inside = (z > MIN_DEPTH_M) & in_image(uv, (h, w))
    own = np.arange(batch.n) if which is None else np.asarray(which, np.int64)
    view = np.repeat(own, np.diff(batch.starts))
    vals = _bilinear(maps, uv[inside], view[inside]).reshape(-1, 1, 2)
    per = np.einsum("nmk,nk->nm", vals, batch.normals_abs[inside])
    ends = np.concatenate([[0], np.cumsum(inside)])[batch.starts]  # rows of `per` per view
    out = np.zeros(batch.n)
    for i in range(batch.n):
        a, b = batch.starts[i], batch.starts[i + 1]
        den = batch.den[i]
        if den <= 0 or ends[i + 1] == ends[i]:
            continue
        num = batch.weights[a:b][inside[a:b]] @ per[ends[i]:ends[i + 1]].copy()
        out[i] = (num / den)[0]
    return out


def camera_edges_many(edges: list[ScanEdges], T_cam_lidar: list[F64], K: list[F64],
                      grey: list[F64], margin_px: float = 2.0) -> list[EdgeView]:
    """`packets.edges.camera_edges` of many sweeps' edge points (each moved by its own
    T_cam_lidar (4, 4), seen through its K (3, 3) in its grey image (h, w)): for views of one
    K and image size, each view's points moved by its own product and the projection, the
    image test and the normals computed for all at once; otherwise view by view. Each
    EdgeView is bit for bit `camera_edges`'s (pinned by a test)."""
    if not edges:
        return []
    shape = np.shape(grey[0])
    if any(not np.array_equal(k, K[0]) for k in K) or any(np.shape(g) != shape for g in grey):
        return [camera_edges(e, T, k, g, margin_px)
                for e, T, k, g in zip(edges, T_cam_lidar, K, grey, strict=True)]
    K0 = np.asarray(K[0], np.float64)
    h, w = shape
    pc = np.concatenate([apply_T(e.points, T) for e, T in zip(edges, T_cam_lidar, strict=True)])
    starts = _starts([len(e.points) for e in edges])
    uv, z = _pinhole(pc, K0, starts)
    keep = (z > MIN_DEPTH_M) & np.isfinite(uv).all(1) & in_image(uv, (h, w), margin_px)
    pc, uv, z = pc[keep], uv[keep], z[keep]
    kept = [keep[a:b] for a, b in pairwise(starts)]
    across = np.concatenate([e.across[k] @ np.asarray(T, np.float64)[:3, :3].T
                             for e, k, T in zip(edges, kept, T_cam_lidar, strict=True)])
    kept_starts = _starts([int(k.sum()) for k in kept])
    uv2, _ = _pinhole(pc + 0.01 * z[:, None] * across, K0, kept_starts)
    nrm = uv2 - uv
    norm = np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.divide(nrm, norm, out=np.zeros_like(nrm), where=norm > 0)
    return [EdgeView(pc[a:b], e.weights[k], nrm[a:b], Kv, np.asarray(g, np.float64))
            for (a, b), e, k, Kv, g in zip(pairwise(kept_starts), edges, kept, K, grey,
                                           strict=True)]


def _starts(sizes: list[int]) -> I64:
    """Each view's first row (n + 1,) of views of `sizes` rows concatenated."""
    out: I64 = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return out


def _pinhole(points: F64, K: F64, starts: I64) -> tuple[F64, F64]:
    """`packets.projection.pinhole` of views' points (P, 3) concatenated at `starts`, one K
    (3, 3): uv (P, 2), z (P,), each view's rows as its own call rounds them."""
    z = points[:, 2]
    pix = rows_product(points, np.asarray(K, np.float64).T, starts)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv: F64 = pix[:, :2] / np.where(z > 0, z, np.nan)[:, None]
    return uv, z
