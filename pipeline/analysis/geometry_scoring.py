"""What the geometry check scores, below the stage's view building (`geometry_views`) and its
cross-view consistency (`geometry_overlap`), which both import it: the odometry read at view
times (`Poses`), a camera's raw views (`RawView`, `CameraSet`) and the LiDAR-edge score of an
edge view on stacked edge maps (`view_scores`, `score_matrix`, `diagonal`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from packets.edges import EdgeView, ScanEdges, edge_sums
from packets.reprojection_consistency import Track
from packets.rigid import rotvec_matrix
from packets.track_batch import BatchTrack
from pipeline.analysis.align_lidar import BodyTrack

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Poses:
    """The odometry read linearly (`packets.reprojection_consistency.Track`: slerp errs by
    below 0.1 deg between 20 Hz samples, far below what the verdict resolves) and each
    sensor's T_base_sensor (4, 4)."""

    track: Track
    body: BodyTrack

    @classmethod
    def of(cls, body: BodyTrack) -> Poses:
        """The linear reading of a recording's `BodyTrack`."""
        return cls(Track(body.base.t, body.base.T), body)

    @cached_property
    def _batch(self) -> BatchTrack | None:
        """The track read at many stamps at once (None for a track that is not the linear
        `Track`, which is read stamp by stamp)."""
        return BatchTrack(self.track.t, self.track.T) if type(self.track) is Track else None

    def sensor_at(self, sensor: str, stamp_ns: float) -> F64 | None:
        """T_odom_sensor (4, 4) at a stamp (ns, odometry clock); None outside the odometry."""
        if sensor not in self.body.T_base:
            return self.body.sensor_at(sensor, stamp_ns)  # its DataError naming the table
        T = self.track.at(stamp_ns)
        return None if T is None else T @ self.body.T_base[sensor]

    def sensors_at(self, sensor: str, stamps_ns: list[int] | list[float]) -> list[F64 | None]:
        """`sensor_at` at every stamp of a list (one type: int or float ns), the odometry
        interpolated for all at once (`packets.track_batch`: bit for bit the same poses)."""
        batch = self._batch
        if sensor not in self.body.T_base or batch is None or not stamps_ns:
            return [self.sensor_at(sensor, s) for s in stamps_ns]
        T, inside = batch.at_many(stamps_ns)
        T_base = self.body.T_base[sensor]
        return [T[k] @ T_base if inside[k] else None for k in range(len(stamps_ns))]


@dataclass(frozen=True)
class RawView:
    """One scored view before the geometry is applied: its sweep's edge points (LiDAR frame),
    the LiDAR's pose T_odom_lidar (4, 4) at the sweep stamp, the image time on the odometry
    clock (ns), K (3, 3), the grey image (h, w) and the sweep stamp (ns, odometry clock)."""

    edges: ScanEdges
    T_odom_lidar: F64
    image_ns: int
    K: F64
    grey: F64
    sweep_ns: int = 0


@dataclass(frozen=True)
class CameraSet:
    """One camera's raw views (time order) and its name; `tried` views were chosen, `flat`
    of them had no image edges."""

    camera: str
    views: list[RawView]
    tried: int
    flat: int
    step_rad: float = 0.0
    """The LiDAR's azimuth step (rad): edges are placed to within half of it."""
    resolution_deg: float = 0.0
    """The sweep's angular resolution (deg, `packets.scan_resolution`; 0: unknown): the
    verdict may fail the camera only when it and the azimuth step are fine enough (a sweep
    whose rings cannot be told apart reads a near-zero azimuth step)."""


def points_scores(v: EdgeView, pts: F64, maps: F64) -> F64:
    """Scores (m,) of edge points `pts` (N, 3) m (the camera frame; `v`'s weights and
    normals) on each of the edge maps stacked (h, w, m, 2): `packets.edges.edge_sums` over
    its denominator (all 0 without weights or without a point in the image)."""
    num, den = edge_sums(v, pts, maps)
    out: F64 = num / den if den > 0 else np.zeros(maps.shape[2])
    return out


def view_scores(v: EdgeView, maps: F64, r_rad: F64 | None = None) -> F64:
    """Scores (m,) of one view's edge points (turned by rotation vector `r_rad` (3,), rad:
    `packets.rigid.rotated`) on each of the edge maps stacked (h, w, m, 2) (`points_scores`)."""
    return points_scores(v, v.points if r_rad is None else v.points @ rotvec_matrix(r_rad), maps)


def score_matrix(views: list[EdgeView], maps: F64) -> F64:
    """S (n, n): view i's edge points scored on edge map j (maps stacked (h, w, n, 2))."""
    return np.stack([view_scores(v, maps) for v in views]) if views else np.zeros((0, 0))


def own_maps(maps: F64) -> list[F64]:
    """Each view's own edge map (h, w, 1, 2), contiguous, of maps stacked (h, w, n, 2) (what
    `diagonal` reads)."""
    return [np.ascontiguousarray(maps[:, :, i:i + 1]) for i in range(maps.shape[2])]


def diagonal(views: list[EdgeView], maps: F64 | list[F64], r_rad: F64 | None = None) -> F64:
    """S[i, i] (n,) only: each view on its own map (maps stacked (h, w, n, 2), or `own_maps`
    of them); the rotation matrix of `r_rad` is built once for every view. The view-by-view
    reference the check's batched scoring (`packets.edge_batch`) is pinned to, bit for bit."""
    own = own_maps(maps) if isinstance(maps, np.ndarray) else maps
    R = None if r_rad is None else rotvec_matrix(r_rad)
    return np.array([points_scores(v, v.points if R is None else v.points @ R, own[i])[0]
                     for i, v in enumerate(views)])
