"""A smooth 6-DoF walk of the body frame `base` in `odom`, with a legged robot's gait sway.

The robot walks a path (a wavy line or a wobbly loop) at constant arc-length speed; yaw follows
the path heading plus a gait wobble, roll/pitch sway with the gait, and the base bobs in height.
Poses are analytic in time, so any stamp can be evaluated exactly (vectorized).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.errors import DataError

F64 = npt.NDArray[np.float64]

GAIT_HZ = 0.9  # stride frequency of the sway
BASE_HEIGHT_M = 0.55


@dataclass(frozen=True)
class PathSpec:
    """Walked path in the ground plane. kind 'line': x = s, y = amp * sin(2 pi x / period);
    kind 'loop': circle of `radius` with radial wobble amp * sin(period * phi) (period = lobes)."""

    kind: str
    length_m: float
    radius: float
    amp: float
    period: float


def path_xy(path: PathSpec, s: npt.ArrayLike) -> F64:
    """Points (N, 2) in metres of the path at parameters s (N,) (metres along it, approx.)."""
    s = np.asarray(s, dtype=np.float64)
    if path.kind == "line":
        return np.stack([s, path.amp * np.sin(2 * np.pi * s / path.period)], axis=-1)
    if path.kind == "loop":
        phi = s / path.radius
        r = path.radius * (1.0 + path.amp * np.sin(path.period * phi))
        return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)
    raise DataError(f"unknown path kind {path.kind!r}")


def _rpy_to_R(roll: F64, pitch: F64, yaw: F64) -> F64:
    """(N, 3, 3) R = Rz(yaw) Ry(pitch) Rx(roll) for angle arrays (N,) in radians."""
    cr, sr, cp, sp, cy, sy = (np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch),
                              np.cos(yaw), np.sin(yaw))  # fmt: skip
    R = np.empty((*roll.shape, 3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


@dataclass(frozen=True)
class Trajectory:
    """T_odom_base(t) for t in seconds since the recording start (t0); speed in m/s."""

    path: PathSpec
    speed_mps: float
    phase: float = 0.0

    def poses(self, t_s: npt.ArrayLike) -> F64:
        """(N, 4, 4) float64 T_odom_base at times t_s (N,) seconds since t0 (may be negative)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        s = self.speed_mps * t
        xy = path_xy(self.path, s)
        d = path_xy(self.path, s + 1e-3) - path_xy(self.path, s - 1e-3)
        heading = np.arctan2(d[:, 1], d[:, 0])
        w = 2 * np.pi * GAIT_HZ * t + self.phase
        yaw = heading + np.deg2rad(2.0) * np.sin(w)
        roll = np.deg2rad(2.5) * np.sin(w + 0.3)
        pitch = np.deg2rad(1.5) * np.sin(2 * w + 0.7) + np.deg2rad(1.0)
        z = BASE_HEIGHT_M + 0.015 * np.sin(2 * w)
        T = np.zeros((t.size, 4, 4))
        T[:, :3, :3] = _rpy_to_R(roll, pitch, yaw)
        T[:, 0, 3], T[:, 1, 3], T[:, 2, 3] = xy[:, 0], xy[:, 1], z
        T[:, 3, 3] = 1.0
        return T

    def twist(self, t_s: npt.ArrayLike, h: float = 1e-3) -> tuple[F64, F64]:
        """Body-frame linear (N, 3) m/s and angular (N, 3) rad/s velocity by central difference."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        Tm, T0, Tp = self.poses(t - h), self.poses(t), self.poses(t + h)
        R0t = np.swapaxes(T0[:, :3, :3], 1, 2)
        v = np.einsum("nij,nj->ni", R0t, (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h))
        dR = np.einsum("nij,njk->nik", R0t, Tp[:, :3, :3] - Tm[:, :3, :3]) / (2 * h)
        w = np.stack([dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0],
                      dR[:, 1, 0] - dR[:, 0, 1]], axis=-1) / 2  # fmt: skip
        return v, w
