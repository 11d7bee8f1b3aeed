"""Camera-LiDAR clock offset from the data: LiDAR depth edges against image edges.

A candidate offset c places each image at stamp - c on the LiDAR clock; the sweep is projected
through the odometry chain at that time. Where the offset is right, the LiDAR's depth
discontinuities (range jumps between neighbouring returns of one ring) land on the image's
intensity edges. The score of a view is the mean blurred image-gradient magnitude at the
projected edge points over the mean at all projected points (1 = no alignment); the estimate
maximizes the summed score over a grid of candidates (Levinson and Thrun's edge objective, used
here on time instead of extrinsics).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
EDGE_REL_JUMP: float = 0.1
"""Relative range jump between neighbouring returns of one ring that marks a depth edge."""
RING_DEG: float = 1.0
"""Elevation spacing of the rings (Hesai XT32: 1 degree); returns are grouped by it."""


def scan_edges(xyz: npt.ArrayLike, t_ns: npt.ArrayLike, rel_jump: float = EDGE_REL_JUMP) -> I64:
    """Indices of the nearer return of every range jump along a ring (foreground silhouettes).

    xyz: (N, 3) metres in the LiDAR frame; t_ns: (N,) firing times (order along a ring).
    Rings are recovered from elevation in RING_DEG bins.
    """
    p = np.asarray(xyz, dtype=np.float64)
    t = np.asarray(t_ns, dtype=np.int64)
    r = np.linalg.norm(p, axis=1)
    ok = np.isfinite(r) & (r > 0)
    idx = np.flatnonzero(ok)
    elev = np.degrees(np.arcsin(np.clip(p[idx, 2] / r[idx], -1.0, 1.0)))
    ring = np.round(elev / RING_DEG).astype(np.int64)
    order = idx[np.lexsort((t[idx], ring))]
    ring_sorted = ring[np.lexsort((t[idx], ring))]
    ra, rb = r[order[:-1]], r[order[1:]]
    jump = (ring_sorted[:-1] == ring_sorted[1:]) & (np.abs(ra - rb) > rel_jump * np.minimum(ra, rb))
    near = np.where(ra < rb, order[:-1], order[1:])[jump]
    out: I64 = np.unique(near)
    return out


def edge_score(grad: npt.ArrayLike, uv_edge: npt.ArrayLike, uv_all: npt.ArrayLike) -> float:
    """Mean of `grad` (H, W) at edge pixels (M, 2) over its mean at all pixels (N, 2) (u, v).

    NaN when either set is empty or the mean over all points is 0.
    """
    g = np.asarray(grad, dtype=np.float64)
    e, a = (np.rint(np.asarray(x, np.float64)).astype(np.int64) for x in (uv_edge, uv_all))
    if e.size == 0 or a.size == 0:
        return float("nan")
    ge, ga = g[e[:, 1], e[:, 0]].mean(), g[a[:, 1], a[:, 0]].mean()
    return float(ge / ga) if ga > 0 else float("nan")


def best_offset(candidates_s: npt.ArrayLike, scores: npt.ArrayLike) -> float:
    """The candidate with the largest finite summed score, refined by a parabola through it and
    its two grid neighbours (candidates evenly spaced, ascending); NaN if no score is finite."""
    c = np.asarray(candidates_s, dtype=np.float64)
    s = np.asarray(scores, dtype=np.float64)
    if not np.isfinite(s).any():
        return float("nan")
    i = int(np.nanargmax(s))
    if 0 < i < c.size - 1 and np.isfinite(s[i - 1 : i + 2]).all():
        den = s[i - 1] - 2 * s[i] + s[i + 1]
        if den < 0:
            return float(c[i] + 0.5 * (s[i - 1] - s[i + 1]) / den * (c[1] - c[0]))
    return float(c[i])
