"""Project LiDAR points into a camera: OpenCV pinhole (optional radial-tangential) or equidistant.

Conventions: `T_cam_lidar` (4, 4) maps LiDAR-frame points into the camera frame (OpenCV: x right,
y down, z forward). Pixel centres sit at integer coordinates, so an image of width W covers
u in [-0.5, W - 0.5]; a point exactly on the right/bottom edge belongs to the last pixel.
Depth is the camera-frame z in metres (eq. 8: d_k > 0).
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from packets._checks import require_finite, require_shape
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]
Bool = npt.NDArray[np.bool_]
CameraModel = Literal["pinhole", "equidistant"]

MIN_DEPTH_M: float = 0.1
"""Points nearer than this camera depth (metres) are dropped and counted as too near.

0.1 m is below the closest return of a Hesai XT32 (0.05 m blind zone aside, the body of the robot
is further away) and keeps 1/mean-depth (eq. 9) at most 10 per metre. Matches the config default.
"""


class Projection(NamedTuple):
    """Per-point projection of one sweep into one view.

    uv: (N, 2) float64 pixel coordinates; -1 where the point is not in front of the camera.
    depth: (N,) float64 camera-frame z in metres (raw, also for dropped points).
    valid: (N,) bool, depth >= min depth and uv inside the image.
    """

    uv: F64
    depth: F64
    valid: Bool


def transform_points(xyz: npt.ArrayLike, T_a_b: npt.ArrayLike) -> F64:
    """Map (N, 3) points from frame b to frame a with the 4x4 `T_a_b`, in float64."""
    pts = np.asarray(xyz, dtype=np.float64)
    T = np.asarray(T_a_b, dtype=np.float64)
    # a contiguous rotation keeps the product on BLAS; numpy's own loop for the transposed view
    # is far slower (docs/benchmarks.md, "View and report")
    out: F64 = pts @ np.ascontiguousarray(T[:3, :3].T) + T[:3, 3]
    return out


def _check_camera(K: F64, model: str, D: F64 | None) -> F64:
    require_shape("K", K, (3, 3))
    require_finite("K", K)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DataError(f"K focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    if model not in ("pinhole", "equidistant"):
        raise DataError(f"camera model must be 'pinhole' or 'equidistant', got {model!r}")
    if D is None:
        return np.zeros(5 if model == "pinhole" else 4)
    dist = np.asarray(D, dtype=np.float64).ravel()
    require_finite("D", dist)
    allowed = (4, 5) if model == "pinhole" else (4,)
    if dist.size not in allowed:
        raise DataError(f"{model} distortion D needs {allowed} coefficients, got {dist.size}")
    return np.concatenate([dist, np.zeros(5 - dist.size)]) if model == "pinhole" else dist


def distort(xn: F64, model: CameraModel, D: F64) -> F64:
    """Apply lens distortion to (N, 2) normalized coordinates x/z, y/z; returns (N, 2) float64."""
    x, y = xn[:, 0], xn[:, 1]
    r2 = x * x + y * y
    if model == "pinhole":
        k1, k2, p1, p2, k3 = D
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=1)
    r = np.sqrt(r2)
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (D[0] + t2 * (D[1] + t2 * (D[2] + t2 * D[3]))))
    scale = np.divide(theta_d, r, out=np.ones_like(r), where=r > 0)
    out: F64 = xn * scale[:, None]
    return out


def in_image(uv: F64, hw: tuple[int, int], margin_px: float = 0.0) -> Bool:
    """(...) bool: pixel coordinates uv (..., 2) inside [-0.5, W-0.5] x [-0.5, H-0.5] (edges
    included; NaN is outside), shrunk by `margin_px` pixels on every side (0.5: the interior
    [0, W-1] x [0, H-1] where a bilinear read has its four neighbours)."""
    h, w = hw
    u, v = uv[..., 0], uv[..., 1]
    lo = margin_px - 0.5
    out: Bool = (u >= lo) & (u <= w - 0.5 - margin_px) & (v >= lo) & (v <= h - 0.5 - margin_px)
    return out


def pinhole(points_cam: npt.ArrayLike, K: npt.ArrayLike) -> tuple[F64, F64]:
    """Pixels uv (..., 2) and z-depths (...) m of camera-frame points (..., 3) m through an
    undistorted pinhole K (3, 3) (last row 0 0 1): uv = (K p)[:2] / z; NaN pixels where z <= 0
    (never inside an image). `project_points` is the general entry (distortion, validity)."""
    cam = np.asarray(points_cam, np.float64)
    z = cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pix = cam @ np.asarray(K, np.float64).T
        uv: F64 = pix[..., :2] / np.where(z > 0, z, np.nan)[..., None]
    return uv, z


def bilinear(image: npt.ArrayLike, uv: F64) -> F64:
    """Image (h, w, ch) read at pixels uv (P, 2) (clamped to the interior [0, w-1] x [0, h-1])
    -> (P, ch) float64 (exact on an image linear in u and v)."""
    img = np.asarray(image, np.float64)
    h, w = img.shape[:2]
    u, v = np.clip(uv[:, 0], 0, w - 1), np.clip(uv[:, 1], 0, h - 1)
    u0 = np.minimum(np.floor(u), max(w - 2, 0)).astype(np.int64)
    v0 = np.minimum(np.floor(v), max(h - 2, 0)).astype(np.int64)
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    out: F64 = (img[v0, u0] * (1 - fu) * (1 - fv) + img[v0, u1] * fu * (1 - fv)
                + img[v1, u0] * (1 - fu) * fv + img[v1, u1] * fu * fv)
    return out


def project_points(
    xyz: npt.ArrayLike,
    K: npt.ArrayLike,
    T_cam_lidar: npt.ArrayLike,
    hw: tuple[int, int],
    model: CameraModel = "pinhole",
    D: npt.ArrayLike | None = None,
    min_depth_m: float = MIN_DEPTH_M,
) -> Projection:
    """Project (N, 3) LiDAR points (metres) into an image of size hw = (H, W) pixels.

    Points with camera depth below `min_depth_m` (including z <= 0, behind the camera) are
    invalid and keep uv = -1; NaN/Inf inputs raise ValueError naming the array.
    """
    pts = np.asarray(xyz, dtype=np.float64)
    require_shape("xyz", pts, (None, 3))
    require_finite("xyz", pts)
    T = np.asarray(T_cam_lidar, dtype=np.float64)
    require_shape("T_cam_lidar", T, (4, 4))
    require_finite("T_cam_lidar", T)
    Km = np.asarray(K, dtype=np.float64)
    dist = _check_camera(Km, model, None if D is None else np.asarray(D, dtype=np.float64))
    if not min_depth_m > 0:
        raise DataError(f"min_depth_m must be > 0, got {min_depth_m}")
    with np.errstate(over="ignore", invalid="ignore"):
        cam = transform_points(pts, T)
    require_finite("camera-frame points (T_cam_lidar applied to xyz)", cam)
    depth = cam[:, 2].copy()
    front = depth >= min_depth_m
    uv = np.full((pts.shape[0], 2), -1.0)
    with np.errstate(over="ignore", invalid="ignore"):
        xn = cam[front, :2] / depth[front, None]
        xd = distort(xn, model, dist)
        uv_f = np.stack(
            [Km[0, 0] * xd[:, 0] + Km[0, 1] * xd[:, 1] + Km[0, 2], Km[1, 1] * xd[:, 1] + Km[1, 2]],
            axis=1,
        )
    finite = np.isfinite(uv_f).all(axis=1)
    uv_f[~finite] = -1.0
    uv[front] = uv_f
    valid = front.copy()
    valid[front] = finite & in_image(uv_f, hw)
    return Projection(uv=uv, depth=depth, valid=valid)


def undistort(xd: F64, model: CameraModel, D: F64, iterations: int = 20) -> F64:
    """Invert `distort` on (N, 2) distorted normalized coordinates (Newton / fixed point)."""
    if model == "equidistant":
        theta_d = np.hypot(xd[:, 0], xd[:, 1])
        theta = theta_d.copy()
        for _ in range(iterations):
            t2 = theta * theta
            f = theta * (1 + t2 * (D[0] + t2 * (D[1] + t2 * (D[2] + t2 * D[3])))) - theta_d
            df = 1 + t2 * (3 * D[0] + t2 * (5 * D[1] + t2 * (7 * D[2] + t2 * 9 * D[3])))
            theta = theta - f / df
        r = np.tan(theta)
        scale = np.divide(r, theta_d, out=np.ones_like(r), where=theta_d > 0)
        return xd * scale[:, None]
    x = xd.copy()
    for _ in range(iterations):
        delta = distort(x, model, D) - x
        x = xd - delta
    return x


def backproject(
    uv: npt.ArrayLike,
    depth: npt.ArrayLike,
    K: npt.ArrayLike,
    model: CameraModel = "pinhole",
    D: npt.ArrayLike | None = None,
) -> F64:
    """Lift (N, 2) pixels with camera depth (N,) metres to (N, 3) camera-frame points, float64."""
    Km = np.asarray(K, dtype=np.float64)
    dist = _check_camera(Km, model, None if D is None else np.asarray(D, dtype=np.float64))
    p = np.asarray(uv, dtype=np.float64)
    z = np.asarray(depth, dtype=np.float64)
    yd = (p[:, 1] - Km[1, 2]) / Km[1, 1]
    xd = (p[:, 0] - Km[0, 2] - Km[0, 1] * yd) / Km[0, 0]
    xn = undistort(np.stack([xd, yd], axis=1), model, dist)
    return np.stack([xn[:, 0] * z, xn[:, 1] * z, z], axis=1)
