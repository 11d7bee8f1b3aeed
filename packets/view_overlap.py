"""Cross-view consistency of a camera's geometry where its views overlap (pure math).

One view's LiDAR edge points, placed in the world by the odometry at its sweep, are read in
another view's image, placed by the odometry at that image's time: C[i, j] is the LiDAR-edge
alignment score (`packets.edges.alignment_score`) of view i's edge points on view j's image
edges. For a pair of views near in time (`near_pairs`) both look at the same edges, so with a
right pose source and frames C[i, j] is about what each view scores on its own image; with a
wrong one the motion between the views is wrong and C[i, j] falls to what unrelated images
score (the shuffled-pairs null of `packets.geometry_verdict`). Only the relative motion
between two views enters C[i, j] (one view's own score does not depend on the pose source
except through the few milliseconds between its sweep and its image): this is what sees a
wrong pose source that leaves each view's own score high.

A pair overlaps when at least `overlap_min_points` of view i's edge points land in view j's
image: `MIN_POINTS`, or half the median edge points a view has in its own image where a sparse
scan gives fewer (at least `FEWEST_POINTS`).
The consistency (`cross_view`): the mean C over the overlapping pairs, its z against the
null's mean and standard deviation, and the mean own score of the same pairs' source views.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.null_stats import z_score

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

MIN_POINTS = 50
"""A view pair overlaps when this many of one view's LiDAR edge points land in the other's
image."""
FEWEST_POINTS = 5
"""A pair never overlaps with fewer edge points than this."""
MAX_LAG = 2
"""Pairs are views at most this many scored views apart (both directions)."""


def near_pairs(n: int, max_lag: int = MAX_LAG) -> I64:
    """Pairs (P, 2) of view indices (i, j), 1 <= |i - j| <= max_lag, of n views in time order."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    lag = np.abs(i - j)
    keep = (lag >= 1) & (lag <= max_lag)
    out: I64 = np.stack([i[keep], j[keep]], axis=1).astype(np.int64)
    return out


def overlap_min_points(own_points: npt.ArrayLike) -> int:
    """Edge points (of one view, in another's image) that make a pair overlap, from the edge
    points (n,) each view has in its own image: min(MIN_POINTS, half their median), at least
    FEWEST_POINTS."""
    p = np.asarray(own_points, np.float64)
    half = 0.5 * float(np.median(p)) if p.size else 0.0
    return max(FEWEST_POINTS, min(MIN_POINTS, int(half)))


@dataclass(frozen=True)
class CrossView:
    """The consistency of the overlapping pairs: how many pairs were tried and overlap, the
    LiDAR edge points that landed over them, the mean cross score, the mean own score of
    their source views, z of the cross score against the null, and why there is no
    consistency to judge ('' when there is)."""

    tried: int
    pairs: int
    points: int
    score: float
    own: float
    z: float
    problem: str = ""

    def line(self) -> str:
        """The consistency in words (one clause)."""
        if self.problem:
            return f"cross-view: inconclusive: {self.problem}"
        return (f"cross-view score {self.score:.4f} vs own {self.own:.4f} (z {self.z:.1f}, "
                f"{self.pairs} overlapping view pairs)")


def cross_view(cross: npt.ArrayLike, points: npt.ArrayLike, own: npt.ArrayLike,
               null_mean: float, null_std: float, min_points: int = MIN_POINTS) -> CrossView:
    """The consistency of P tried pairs: `cross` (P,) C[i, j], `points` (P,) view i's edge
    points landing in view j's image, `own` (P,) view i's own score; z against the null
    (mean, std); `no overlap` when no pair has `min_points` points."""
    c = np.asarray(cross, np.float64)
    p = np.asarray(points, np.int64)
    o = np.asarray(own, np.float64)
    if not (c.shape == p.shape == o.shape) or c.ndim != 1:
        raise ValueError(f"cross {c.shape}, points {p.shape} and own {o.shape} must be one (P,)")
    use = p >= min_points
    if not use.any():
        most = int(p.max()) if len(p) else 0
        return CrossView(len(c), 0, 0, 0.0, 0.0, 0.0,
                         f"no overlap: no view pair of {len(c)} shares {min_points} LiDAR edge "
                         f"points (at most {most})")
    score = float(c[use].mean())
    return CrossView(len(c), int(use.sum()), int(p[use].sum()), score, float(o[use].mean()),
                     z_score(score, null_mean, null_std))
