"""How finely a LiDAR sweep samples directions (pure math, no I/O).

The geometry verdict may only call a camera `failed` when the LiDAR places its edges finely
enough (`packets.geometry_verdict.Thresholds.max_step_deg`). The step along a ring
(`pipeline.analysis.geometry_views.azimuth_step`) reads it from each point's next neighbour on
its ring; that needs rings told apart, which fails when a sweep's columns are far coarser than
its rings are apart (a 32-ring sweep of 32 columns: the "next on the ring" found is the same
column's point on the next ring, so the step reads as ~0 and a sweep of 11 deg columns passed
as fine). The density bound does not need rings: a sweep of N directions over a solid angle
of A deg^2 has A / N deg^2 per point, the product of its azimuth and elevation steps, so the
coarser of the two is at least sqrt(A / N). The resolution used is the larger of the two
estimates: never finer than the density allows.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

AZIMUTH_BINS = 36
"""Azimuth sectors (10 deg) whose occupied share gives the sweep's azimuth span."""

EDGE_PERCENTILE = 1.0
"""The elevation span runs from this percentile to 100 minus it (a stray point is no span)."""


def directions_deg(xyz: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Azimuth and elevation (N', 2) deg of the finite, non-zero points of `xyz` (N, 3) m."""
    p = np.asarray(xyz, np.float64).reshape(-1, 3)
    r = np.linalg.norm(p, axis=1)
    keep = np.isfinite(r) & (r > 0)
    p, r = p[keep], r[keep]
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    el = np.degrees(np.arcsin(np.clip(p[:, 2] / r, -1.0, 1.0)))
    return np.stack([az, el], axis=1)


def solid_angle_deg2(dirs: npt.NDArray[np.float64]) -> float:
    """The area (deg^2, azimuth x elevation) a sweep's directions (N, 2) deg cover: the share
    of occupied 10-deg azimuth sectors x 360, times the elevation span between the
    `EDGE_PERCENTILE` percentiles (at least 1 deg: a single ring still has a height)."""
    if len(dirs) == 0:
        return 0.0
    sectors = np.floor((dirs[:, 0] + 180.0) / (360.0 / AZIMUTH_BINS)).astype(np.int64)
    occupied = len(np.unique(np.clip(sectors, 0, AZIMUTH_BINS - 1)))
    lo, hi = np.percentile(dirs[:, 1], [EDGE_PERCENTILE, 100.0 - EDGE_PERCENTILE])
    return float(occupied * 360.0 / AZIMUTH_BINS * max(1.0, hi - lo))


def density_step_deg(xyz: npt.ArrayLike) -> float:
    """The coarser angular step of the sweep `xyz` (N, 3) m is at least this (deg):
    sqrt(solid angle / points); 0 for fewer than 5 points (unknown)."""
    dirs = directions_deg(xyz)
    if len(dirs) < 5:
        return 0.0
    return float(np.sqrt(solid_angle_deg2(dirs) / len(dirs)))


def scan_resolution_deg(ring_step_deg: float, xyz: npt.ArrayLike) -> float:
    """The angular resolution (deg) a verdict may rely on: the ring-neighbour step
    `ring_step_deg` or the density bound of `xyz` (N, 3) m, whichever is coarser."""
    return max(float(ring_step_deg), density_step_deg(xyz))
