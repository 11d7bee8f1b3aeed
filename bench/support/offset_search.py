"""The clock-offset estimator over views (pure): candidate grid, per-view scores, the estimate.

`bench.support.time_offset` scores one projection; this module scores one view over every
candidate offset and turns the summed scores of many views into the estimate. Reading images,
sweeps and the pose chain is the caller's (`bench.offset_estimate`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from bench.support.time_offset import best_offset, edge_score, scan_edges
from packets.projection import project_points

F64 = npt.NDArray[np.float64]
CANDIDATES_S: F64 = np.round(np.arange(-0.15, 0.1501, 0.005), 6)
"""Candidate offsets (s): -150 ms to +150 ms in 5 ms steps (61 values, 0 included)."""


def view_scores(grad: F64, xyz: npt.ArrayLike, t_ns: npt.ArrayLike, K: F64,
                transforms: Sequence[F64 | None], hw: tuple[int, int]) -> F64:
    """Edge-alignment score of one view for each candidate (0 where undefined).

    grad: (H, W) blurred gradient magnitude of the rectified image; xyz: (N, 3) sweep points
    (m, LiDAR frame); t_ns: (N,) their firing times; K: (3, 3) output intrinsics;
    transforms: per candidate, T_cam_lidar (4, 4) at the image time moved by the candidate, or
    None where the pose chain does not cover it. Returns (len(transforms),) float64.
    """
    edges = scan_edges(xyz, t_ns)
    out = np.zeros(len(transforms))
    for i, T in enumerate(transforms):
        if T is None:
            continue
        proj = project_points(xyz, K, T, hw)
        s = edge_score(grad, proj.uv[edges][proj.valid[edges]], proj.uv[proj.valid])
        out[i] = s if np.isfinite(s) else 0.0
    return out


def estimate(candidates_s: F64, total: F64, views: int) -> dict[str, Any]:
    """The estimate from the summed scores (candidates,): the best candidate (s), the number of
    views, and the peak score over the score at the candidate nearest 0 (NaN if all zero)."""
    peak = (float(total.max() / total[np.argmin(np.abs(candidates_s))]) if total.any()
            else float("nan"))
    return {"estimated_s": best_offset(candidates_s, total), "views": views,
            "score_peak_over_zero": peak}
