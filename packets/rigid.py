"""Rigid motions of point sets beside `packets.poses` (4x4 algebra): a frame change of points,
into a camera from the world, pixels with depth lifted into the world, and small rotations
given as rotation vectors.

Conventions: `T_world_cam` (4, 4) float64 maps camera-frame points into the world (metres);
cameras are OpenCV pinholes (x right, y down, z forward, K in pixels, pixel centres at integer
coordinates); rotation vectors are in radians about the camera axes. Every result is float64.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from packets.poses import make_T

F64 = npt.NDArray[np.float64]


def apply_T(points: npt.ArrayLike, T_a_b: npt.ArrayLike) -> F64:
    """Points (..., 3) of frame b moved into frame a by the 4x4 `T_a_b`: R p + t, float64.

    The same map as `packets.projection.transform_points`, in the arithmetic the reprojection
    and edge code always used (a product with the transposed rotation view): on a few points
    or a one-column grid the two round differently in the last bit, so each keeps its callers'
    results bit for bit (transform_points: the LiDAR sweeps into the cameras, on BLAS)."""
    T = np.asarray(T_a_b, np.float64)
    out: F64 = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
    return out


def camera_from_world(points: npt.ArrayLike, T_world_cam: npt.ArrayLike) -> F64:
    """Camera-frame points (..., 3) m of world points (..., 3) m: R^T (p - t)."""
    T = np.asarray(T_world_cam, np.float64)
    out: F64 = (np.asarray(points, np.float64) - T[:3, 3]) @ T[:3, :3]  # row vectors
    return out


def lift_pixels(uv: npt.ArrayLike, z: npt.ArrayLike, K: npt.ArrayLike,
                T_world_cam: npt.ArrayLike) -> F64:
    """World points (..., 3) m of pixels uv (..., 2) at z-depths z (...) m seen by an
    undistorted pinhole K (3, 3) posed at T_world_cam (4, 4): T [z K^-1 (u, v, 1)]."""
    px = np.asarray(uv, np.float64)
    rays = np.concatenate([px, np.ones_like(px[..., :1])], -1) @ np.linalg.inv(
        np.asarray(K, np.float64)).T  # (..., 3), z = 1
    return apply_T(rays * np.asarray(z, np.float64)[..., None], T_world_cam)


def quat_pose_T(quat: npt.ArrayLike, pos: npt.ArrayLike) -> F64:
    """Transforms (..., 4, 4) of quaternions (..., 4) (x, y, z, w, normalized here) and
    positions (..., 3) m, the rotation in scipy's arithmetic (`Rotation.from_quat`).

    The same map as `make_T(packets.poses.quat_to_rot(quat), pos)`, which ingest uses; the two
    round differently in the last bit of about a third of the entries (<= 7e-16). The edge
    alignment's odometry track (`pipeline.analysis.align_lidar.body_track`) always read this
    one, and the geometry stage's stored table changes with the other (checked 2026-11-28:
    `index/<recording>/geometry.parquet` differs), so both stay, each for its callers."""
    q = np.asarray(quat, np.float64)
    return make_T(Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(*q.shape[:-1], 3, 3),
                  pos)


def rotvec_matrix(r_rad: Sequence[float] | F64) -> F64:
    """The rotation matrix (3, 3) exp([r]) of rotation vector r (3,) rad."""
    out: F64 = Rotation.from_rotvec(np.asarray(r_rad, np.float64)).as_matrix()
    return out


def rotation_T(r_rad: Sequence[float] | F64) -> F64:
    """The 4 x 4 rigid transform of rotation vector r (3,) rad (no translation)."""
    return make_T(rotvec_matrix(r_rad), np.zeros(3))


def rotated(points: F64, r_rad: Sequence[float] | F64) -> F64:
    """Points (N, 3) of a camera frame seen from the camera turned by rotation vector r (3,)
    rad: exp([r])^T p."""
    out: F64 = points @ rotvec_matrix(r_rad)  # rows p^T R = (R^T p)^T
    return out
