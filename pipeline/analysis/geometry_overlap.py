"""Cross-view consistency of one camera's scored views (`packets.view_overlap`): each view's
LiDAR edge points, placed by the odometry at its sweep, read in the images of the views near
it in time, placed by the odometry at their image times."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from packets.edge_batch import EdgeBatch, camera_edges_many, own_scores
from packets.geometry_verdict import NullTest
from packets.view_overlap import (
    MAX_LAG,
    CrossView,
    cross_view,
    near_pairs,
    overlap_min_points,
)
from pipeline.analysis.geometry_scoring import CameraSet, Poses

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


def cross_arrays(cs: CameraSet, body: Poses, scored: list[int], maps: F64,
                 max_lag: int = MAX_LAG) -> tuple[F64, I64, I64]:
    """For the near pairs (i, j) of the scored views (`scored`: indices into `cs.views`, maps
    stacked (h, w, n, 2) in that order): C[i, j] (P,), the edge points of view i landing in
    view j's image (P,), and the pairs (P, 2)."""
    views = [cs.views[k] for k in scored]
    T_cam = [np.eye(4) if T is None else T  # edge_views has refused it already
             for T in body.sensors_at(cs.camera, [v.image_ns for v in views])]
    pairs = near_pairs(len(views), max_lag)
    seen = camera_edges_many(
        [views[i].edges for i, _ in pairs],
        [np.asarray(np.linalg.solve(T_cam[j], views[i].T_odom_lidar), np.float64)
         for i, j in pairs], [views[j].K for _, j in pairs], [views[j].grey for _, j in pairs])
    points = np.array([len(ev.points) for ev in seen], np.int64)
    batch = EdgeBatch.of(seen)  # each pair's score as `view_scores` on map j, bit for bit
    scores = own_scores(batch, batch.points, maps, pairs[:, 1] if len(pairs) else None)
    return scores, points, pairs


def cross_check(cs: CameraSet, body: Poses, scored: list[int], maps: F64, own: F64,
                own_points: list[int], test: NullTest) -> CrossView:
    """The camera's cross-view consistency against its null test (`own` (n,): each scored
    view's score on its own image; `own_points` (n,): its edge points there)."""
    scores, points, pairs = cross_arrays(cs, body, scored, maps)
    least = overlap_min_points(own_points)
    return cross_view(scores, points, own[pairs[:, 0]] if len(pairs) else np.zeros(0),
                      test.null_mean, test.null_std, least)
