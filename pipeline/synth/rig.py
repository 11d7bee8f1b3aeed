"""The sensor rig: GrandTour-like static calibration tree and equidistant (fisheye) cameras.

Frames (parent -> child, each edge T_parent_child maps child points into the parent):
`base -> box_base -> hdr_base -> hdr_{front,left,right}` and `box_base -> hesai_lidar`.
Camera frames are optical (OpenCV: x right, y down, z forward); body frames are x forward,
y left, z up. Every mission perturbs extrinsics and intrinsics slightly (seeded), as real
calibration differs per mission.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.poses import compose, make_T
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]

CAMERA_NAMES = ("front", "left", "right")
CAMERA_YAW = {"front": 0.0, "left": np.pi / 2, "right": -np.pi / 2}
# optical axes expressed in a body frame: x_opt = -y, y_opt = -z, z_opt = +x
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
THETA_CORNER = np.deg2rad(80.0)  # incidence angle at the image corner (equidistant, < 90 deg)


def _R(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> F64:
    """R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cy, sy, cp, sp, cr, sr = (np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch),
                              np.cos(roll), np.sin(roll))  # fmt: skip
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    R: F64 = Rz @ Ry @ Rx
    return R


@dataclass(frozen=True)
class FisheyeCamera:
    """Equidistant camera: r = f * theta_d, theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)
    (OpenCV cv2.fisheye); K (3, 3), D (4,), size in pixels; pixel centres at integer u, v."""

    name: str
    frame_id: str
    width: int
    height: int
    K: F64
    D: F64
    model: str = "equidistant"
    """CameraInfo distortion model: equidistant (above), or a pinhole with OpenCV's radial-
    tangential distortion: plumb_bob (D: k1, k2, p1, p2, k3) or rational_polynomial (D: k1,
    k2, p1, p2, k3, k4, k5, k6)."""

    def theta_d(self, theta: F64) -> F64:
        """Distorted angle for incidence angles theta (rad)."""
        t2 = theta * theta
        k1, k2, k3, k4 = self.D
        out: F64 = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        return out

    def pixel_rays(self) -> npt.NDArray[np.float32]:
        """Unit ray directions (H, W, 3) float32 in the optical frame through every pixel centre."""
        if self.model != "equidistant":
            return self._pinhole_rays()
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        fx, fy, cx, cy, skew = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2], self.K[0, 1]
        y = (v - cy) / fy
        x = (u - cx - skew * y) / fx
        rd = np.hypot(x, y)  # = theta_d
        theta = rd.copy()
        for _ in range(30):  # Newton on theta_d(theta) = rd (monotone for these coefficients)
            h = 1e-7
            f = self.theta_d(theta) - rd
            df = (self.theta_d(theta + h) - self.theta_d(theta - h)) / (2 * h)
            theta = theta - f / df
        if not np.isfinite(theta).all() or theta.max() >= np.pi / 2 - 1e-3:
            raise DataError(
                f"camera {self.name}: pixels reach {np.rad2deg(np.nanmax(theta)):.1f} deg "
                "off-axis; "
                f"z-depth needs < 90 deg (K={self.K.tolist()}, D={self.D.tolist()})"
            )
        scale = np.where(rd > 1e-12, np.sin(theta) / np.maximum(rd, 1e-12), 1.0)
        rays = np.stack([x * scale, y * scale, np.cos(theta)], axis=-1)
        return rays.astype(np.float32)


    def _pinhole_rays(self) -> npt.NDArray[np.float32]:
        """Rays of a pinhole camera with radial-tangential distortion (cv2.undistortPoints,
        iterated to convergence)."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        xd, yd = ((u - cx) / fx).ravel(), ((v - cy) / fy).ravel()
        x, y = xd.copy(), yd.copy()
        for _ in range(60):  # fixed point of the radial-tangential model (mild distortion)
            dx, dy, radial = self._distortion(x, y)
            x, y = (xd - dx) / radial, (yd - dy) / radial
        dx, dy, radial = self._distortion(x, y)
        if np.abs(x * radial + dx - xd).max() > 1e-9 or np.abs(y * radial + dy - yd).max() > 1e-9:
            raise DataError(f"camera {self.name}: {self.model} distortion {self.D.tolist()} "
                            "does not invert over the image")
        rays = np.stack([x, y, np.ones_like(x)], axis=1)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        return rays.reshape(self.height, self.width, 3).astype(np.float32)


    def _distortion(self, x: F64, y: F64) -> tuple[F64, F64, F64]:
        """Tangential offsets and radial factor of normalized points (OpenCV's model)."""
        d = np.zeros(8)
        d[: self.D.size] = self.D
        k1, k2, p1, p2, k3, k4, k5, k6 = d
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return dx, dy, radial


PINHOLE_D = {"plumb_bob": np.array([-0.06, 0.012, 0.0004, -0.0003, 0.0]),
             "rational_polynomial": np.array([-0.05, 0.01, 0.0004, -0.0003, 0.0, 0.02, 0.0,
                                              0.0])}  # fmt: skip
PINHOLE_CORNER = np.deg2rad(50.0)
"""Off-axis angle at a pinhole camera's image corner (a pinhole cannot see 80 deg)."""


@dataclass(frozen=True)
class Rig:
    """Static edges (parent, child, T_parent_child), cameras by name, and the LiDAR frame."""

    edges: list[tuple[str, str, F64]]
    cameras: dict[str, FisheyeCamera]
    lidar_frame: str = "hesai_lidar"
    base_frame: str = "base"

    def T_base(self, frame: str) -> F64:
        """(4, 4) T_base_frame composed down the static tree."""
        parent_of = {child: (parent, T) for parent, child, T in self.edges}
        chain: list[F64] = []
        node = frame
        while node != self.base_frame:
            if node not in parent_of:
                raise DataError(f"frame {frame!r} is not connected to {self.base_frame!r}")
            parent, T = parent_of[node]
            chain.append(T)
            node = parent
        return compose(*reversed(chain)) if chain else np.eye(4)


def _camera(name: str, width: int, height: int, rng: np.random.Generator,
            model: str = "equidistant") -> FisheyeCamera:  # fmt: skip
    """Intrinsics scaled to the image size so the corner sits near THETA_CORNER (a pinhole
    `model`: near PINHOLE_CORNER)."""
    if model != "equidistant":
        cam = _camera(name, width, height, rng)
        f = np.hypot(width / 2, height / 2) / np.tan(PINHOLE_CORNER)
        K = cam.K.copy()
        K[0, 0], K[1, 1] = f, f * K[1, 1] / K[0, 0]
        return FisheyeCamera(name, cam.frame_id, width, height, K, PINHOLE_D[model], model)
    f = np.hypot(width / 2, height / 2) / THETA_CORNER * rng.uniform(0.98, 1.02)
    cx = (width - 1) / 2 + rng.uniform(-0.01, 0.01) * width
    cy = (height - 1) / 2 + rng.uniform(-0.01, 0.01) * height
    K = np.array([[f, 0.0, cx], [0.0, f * rng.uniform(0.997, 1.003), cy], [0.0, 0.0, 1.0]])
    D = np.array([0.03, -0.01, 0.002, -0.0003]) * rng.uniform(0.8, 1.2, 4)
    return FisheyeCamera(name, f"hdr_{name}", width, height, K, D)


def camera_yaws(cameras: Sequence[str]) -> dict[str, float]:
    """Yaw (rad, about the body z axis) of every camera of the rig: front, left and right face
    those ways (always built, as GrandTour's HDR triple); any other name in `cameras` is placed
    around the rig in list order (the k-th of n at 2 pi (k + 1/2) / n)."""
    extra = [c for c in dict.fromkeys(cameras) if c not in CAMERA_YAW]
    yaws = dict(CAMERA_YAW)
    yaws.update({c: float(2 * np.pi * (k + 0.5) / len(extra) - np.pi)
                 for k, c in enumerate(extra)})  # fmt: skip
    return yaws


def build_rig(width: int, height: int, rng: np.random.Generator,
              camera_frame: str | Callable[[str], str] = "hdr_{camera}",
              lidar_frame: str = "hesai_lidar", base_frame: str = "base",
              camera_model: str = "equidistant", cameras: Sequence[str] = ()) -> Rig:  # fmt: skip
    """The calibration of one mission: GrandTour-like layout with small seeded perturbations.

    `camera_frame`: a `{camera}` template or a function of the camera name; `cameras`: names
    besides front, left and right to carry (`camera_yaws`), built after those three.
    """
    frame_of = camera_frame if callable(camera_frame) else (
        lambda name: camera_frame.format(camera=name))  # fmt: skip

    def jitter(yaw: float, pitch: float, roll: float, t: list[float]) -> F64:
        a = np.deg2rad(0.5) * rng.normal(size=3)
        return make_T(
            _R(yaw + a[0], pitch + a[1], roll + a[2]), np.asarray(t) + rng.normal(0, 0.005, 3)
        )

    edges: list[tuple[str, str, F64]] = [
        (base_frame, "box_base", jitter(0.0, 0.0, 0.0, [-0.12, 0.0, 0.22])),
        ("box_base", "hdr_base", jitter(0.0, 0.0, 0.0, [0.16, 0.0, 0.08])),
        ("box_base", lidar_frame, jitter(np.pi / 2, 0.0, 0.0, [0.0, 0.0, 0.28])),
    ]
    models = {}
    for name, yaw in camera_yaws(cameras).items():
        frame = frame_of(name)
        T = jitter(yaw, np.deg2rad(12.0), 0.0, [0.04 * np.cos(yaw), 0.04 * np.sin(yaw), 0.0])
        T[:3, :3] = T[:3, :3] @ R_BODY_OPTICAL
        edges.append(("hdr_base", frame, T))
        cam = _camera(name, width, height, rng, camera_model)
        models[name] = FisheyeCamera(name, frame, cam.width, cam.height, cam.K, cam.D, cam.model)
    return Rig(edges, models, lidar_frame, base_frame)


SECOND_LIDAR_MOUNT = make_T(_R(-np.pi / 2, np.deg2rad(28.0), 0.0), [0.18, 0.06, -0.05])
"""T_box_base_second: the second LiDAR (`synth.second_lidar`) forward on the box, turned and
tilted down 28 deg (fixed, no seeded jitter: the other edges draw the same numbers)."""


def with_second_lidar(rig: Rig, frame: str) -> Rig:
    """`rig` with a second LiDAR frame `frame` on the box (`SECOND_LIDAR_MOUNT`)."""
    return Rig([*rig.edges, ("box_base", frame, SECOND_LIDAR_MOUNT.copy())], rig.cameras,
               rig.lidar_frame, rig.base_frame)
