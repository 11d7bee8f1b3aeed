"""A smooth 6-DoF walk of the body frame `base` in `odom`, with a legged robot's gait sway.

The robot walks a path (a wavy line or a wobbly loop); yaw follows the path heading plus a gait
wobble, roll/pitch sway with the gait, and the base bobs in height. A `Motion` profile varies the
speed along the path (v(t) = v (1 + a sin(2 pi t / P_v)), never negative) and adds turning of the
body on top of the heading (extra yaw with rate Omega cos(2 pi t / P_w), peak Omega rad/s, as a
legged robot turns on the spot; with a = 1 the speed minima are stops). Poses are analytic in
time, so any stamp can be evaluated exactly (vectorized).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

from schemas.config import SynthConfig
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
class Motion:
    """Speed swing and turning on top of the walk (all zero: constant speed, heading yaw).

    speed_variation a in [0, 1]: v(t) = v (1 + a sin(2 pi t / speed_period_s)).
    yaw_rate_max_rps Omega >= 0: extra yaw Omega P_w / (2 pi) sin(2 pi t / P_w), whose rate
    Omega cos(2 pi t / P_w) peaks at Omega (rad/s); P_w = yaw_period_s.
    """

    speed_variation: float = 0.0
    speed_period_s: float = 8.0
    yaw_rate_max_rps: float = 0.0
    yaw_period_s: float = 6.0

    def arc(self, speed_mps: float, t: F64) -> F64:
        """Arc length s(t) (metres, (N,)) walked since t = 0: the integral of v(t)."""
        s = speed_mps * t
        if self.speed_variation:
            w = 2 * np.pi / self.speed_period_s
            s = s + speed_mps * self.speed_variation * (1.0 - np.cos(w * t)) / w
        return s

    def extra_yaw(self, t: F64) -> F64:
        """Turning on top of the path heading (radians, (N,))."""
        if not self.yaw_rate_max_rps:
            return np.zeros_like(t)
        w = 2 * np.pi / self.yaw_period_s
        return self.yaw_rate_max_rps / w * np.sin(w * t)

    def max_speed_factor(self) -> float:
        """Largest v(t) / v: how much longer than v t the walked path can get."""
        return 1.0 + self.speed_variation


@dataclass(frozen=True)
class Trajectory:
    """T_odom_base(t) for t in seconds since the recording start (t0); speed in m/s."""

    path: PathSpec
    speed_mps: float
    phase: float = 0.0
    motion: Motion = Motion()

    def poses(self, t_s: npt.ArrayLike) -> F64:
        """(N, 4, 4) float64 T_odom_base at times t_s (N,) seconds since t0 (may be negative)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        s = self.motion.arc(self.speed_mps, t)
        xy = path_xy(self.path, s)
        d = path_xy(self.path, s + 1e-3) - path_xy(self.path, s - 1e-3)
        heading = np.arctan2(d[:, 1], d[:, 0])
        w = 2 * np.pi * GAIT_HZ * t + self.phase
        yaw = heading + np.deg2rad(2.0) * np.sin(w) + self.motion.extra_yaw(t)
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


def motion_of(cfg: SynthConfig) -> Motion:
    """The speed swing and turning a synth configuration asks for."""
    return Motion(cfg.speed_variation, cfg.speed_period_s, cfg.yaw_rate_max_rps, cfg.yaw_period_s)


def motion_json(motion: Motion) -> dict[str, float]:
    """The motion parameters as recorded in scene.json's trajectory section."""
    return {k: float(v) for k, v in asdict(motion).items()}
