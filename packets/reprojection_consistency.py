"""Reprojection consistency of a camera's views (pure math): how well do two views agree on
the appearance of the LiDAR points both see, and which clock offset and extrinsic rotation
make them agree best.

World points X (N, 3) m are the target view's supported cells lifted with its packet depth
and recorded pose (`packets.reprojection.lift`): where the LiDAR put them, whatever the camera's
timing. A candidate (c, r) places each view i at the pose of the camera's recorded track at
stamp_i - c (a camera clock ahead of the LiDAR's by c s), right-multiplied by the rotation
exp([r]) (rad, about the camera axes: an extrinsic rotation error). Both images are read at
X's projections (bilinear), and the photometric error of a pair is the mean squared
difference (grey levels^2, float64) over the points inside both images.

Only relative errors between views show: two views of one camera share its clock and
extrinsics, so an error is seen through how differently it moves the points of the two views
(their depth and pose differences). Pairs with a wide baseline see it best.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline, Slerp

from packets.projection import bilinear, in_image
from packets.reprojection import project, subcell_pixels
from packets.rigid import lift_pixels, rotation_T

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Pair:
    """One view pair: images (h, w, 3) uint8 or float, K (3, 3) each, stamps (ns), and the
    world points X (N, 3) lifted from view a (m)."""

    image_a: npt.NDArray[np.generic]
    image_b: npt.NDArray[np.generic]
    K_a: F64
    K_b: F64
    stamp_a_ns: int
    stamp_b_ns: int
    points: F64


def lift_cells(depth: F64, K: F64, T_world_cam: F64, image_hw: tuple[int, int],
               per_side: int = 4) -> F64:
    """World points (N, 3) of `per_side`^2 pixels spread over every supported cell of an
    (H, W) depth grid (m; 0 = no support), each at its cell's depth (a fronto-parallel facet)."""
    ok = depth > 0
    uv = subcell_pixels(depth.shape, image_hw, per_side)[ok].reshape(-1, 2)
    return lift_pixels(uv, np.repeat(depth[ok], per_side * per_side), K, T_world_cam)


class Track:
    """A camera's recorded poses T_world_cam (N, 4, 4) at stamps (N,) ns (strictly increasing),
    read at any time between them: linear translation, slerp rotation."""

    def __init__(self, stamps_ns: npt.ArrayLike, T_world_cam: npt.ArrayLike) -> None:
        self.t = np.asarray(stamps_ns, np.int64)
        self.T = np.asarray(T_world_cam, np.float64)
        if self.t.size < 2 or bool((np.diff(self.t) <= 0).any()):
            raise ValueError("a track needs >= 2 strictly increasing stamps")
        rel = (self.t - self.t[0]).astype(np.float64) * 1e-9
        self._rel0 = self.t[0]
        self._slerp = Slerp(rel, Rotation.from_matrix(self.T[:, :3, :3]))

    def at(self, stamp_ns: float) -> F64 | None:
        """T_world_cam (4, 4) at a stamp (ns; None outside the recorded span)."""
        if stamp_ns < self.t[0] or stamp_ns > self.t[-1]:
            return None
        s = (stamp_ns - self._rel0) * 1e-9
        rel = (self.t - self._rel0) * 1e-9
        out = np.eye(4)
        out[:3, :3] = self._slerp([s]).as_matrix()[0]
        out[:3, 3] = [np.interp(s, rel, self.T[:, k, 3]) for k in range(3)]
        return out


class CubicTrack(Track):
    """A track read by cubic splines through the `half_window` samples either side of each
    query (rotation: scipy's `RotationSpline`, C2 in angular rate; translation: a `CubicSpline`
    per axis), where `Track` is linear between neighbours. A pose stream sampled coarsely
    against the motion is read to its curvature: between 20 Hz samples of a body yawing at up
    to 1.5 rad/s with a 2 s period, slerp errs by up to 0.084 deg, the cubic (6 samples a side)
    by 6e-5 deg (4 a side: 2e-3). Exactly the recorded pose at a sample's stamp; the linear
    `Track` where fewer than 4 samples surround a query."""

    def __init__(self, stamps_ns: npt.ArrayLike, T_world_cam: npt.ArrayLike,
                 half_window: int = 6) -> None:
        super().__init__(stamps_ns, T_world_cam)
        if half_window < 2:
            raise ValueError(f"half_window {half_window} must be >= 2")
        self.half_window = half_window

    def at(self, stamp_ns: float) -> F64 | None:
        """T_world_cam (4, 4) at a stamp (ns; None outside the recorded span)."""
        if stamp_ns < self.t[0] or stamp_ns > self.t[-1]:
            return None
        i = int(np.searchsorted(self.t, stamp_ns))
        if i < self.t.size and self.t[i] == stamp_ns:
            exact: F64 = self.T[i].copy()
            return exact
        lo, hi = max(0, i - self.half_window), min(self.t.size, i + self.half_window)
        if hi - lo < 4:
            return super().at(stamp_ns)
        rel = (self.t[lo:hi] - self.t[lo]).astype(np.float64) * 1e-9
        s = float(stamp_ns - self.t[lo]) * 1e-9
        out = np.eye(4)
        out[:3, :3] = RotationSpline(rel, Rotation.from_matrix(self.T[lo:hi, :3, :3]))(
            [s]).as_matrix()[0]
        out[:3, 3] = CubicSpline(rel, self.T[lo:hi, :3, 3])(s)
        return out


def pair_error(pair: Pair, T_a: F64, T_b: F64) -> tuple[float, int]:
    """(mean squared photometric difference, points used) of a pair at candidate poses;
    (NaN, 0) when no point is inside both images."""
    hw_a, hw_b = pair.image_a.shape[:2], pair.image_b.shape[:2]
    uv_a, _ = project(pair.points, pair.K_a, T_a)
    uv_b, _ = project(pair.points, pair.K_b, T_b)
    both = in_image(uv_a, (hw_a[0], hw_a[1])) & in_image(uv_b, (hw_b[0], hw_b[1]))
    n = int(both.sum())
    if n == 0:
        return float("nan"), 0
    diff = bilinear(pair.image_a, uv_a[both]) - bilinear(pair.image_b, uv_b[both])
    return float(np.mean(diff * diff)), n


def objective(pairs: Sequence[Pair], track: Track, offset_s: float,
              r_rad: Sequence[float] | F64) -> float:
    """Mean over pairs of the photometric error at candidate (offset, rotation); pairs whose
    shifted stamps leave the track or see no common point are left out (inf if all are)."""
    E, c = rotation_T(r_rad), offset_s * 1e9
    errs = []
    for p in pairs:
        Ta, Tb = track.at(p.stamp_a_ns - c), track.at(p.stamp_b_ns - c)
        if Ta is None or Tb is None:
            continue
        e, n = pair_error(p, Ta @ E, Tb @ E)
        if n:
            errs.append(e)
    return float(np.mean(errs)) if errs else float("inf")


def _refine(xs: F64, ys: F64) -> float:
    """The grid minimum refined by a parabola through it and its neighbours."""
    i = int(np.argmin(ys))
    if 0 < i < len(xs) - 1 and np.isfinite(ys[i - 1:i + 2]).all():
        y0, y1, y2 = ys[i - 1:i + 2]
        den = y0 - 2 * y1 + y2
        if den > 0:
            return float(xs[i] + 0.5 * (y0 - y2) / den * (xs[i + 1] - xs[i]))
    return float(xs[i])


@dataclass(frozen=True)
class Estimate:
    """The sweep's answer: clock offset (s), rotation vector (rad), the objective at the
    recorded calibration (0, 0) and at the estimate."""

    offset_s: float
    rotation_rad: tuple[float, float, float]
    error_nominal: float
    error_min: float


def sweep(pairs: Sequence[Pair], track: Track, offsets_s: F64, angles_rad: F64,
          rounds: int = 3) -> Estimate:
    """Coordinate descent over the clock offset (grid `offsets_s`) and each rotation axis
    (grid `angles_rad` about the current value), each 1-D minimum parabola-refined."""
    c, r = 0.0, np.zeros(3)
    for _ in range(rounds):
        ys = np.array([objective(pairs, track, o, r) for o in offsets_s])
        c = _refine(offsets_s, ys)
        for k in range(3):
            grid = r[k] + angles_rad
            ys = np.array([objective(pairs, track, c, np.where(np.arange(3) == k, a, r))
                           for a in grid])
            r[k] = _refine(grid, ys)
        offsets_s = c + (offsets_s - offsets_s.mean()) * 0.5
        angles_rad = angles_rad * 0.5
    return Estimate(c, (float(r[0]), float(r[1]), float(r[2])),
                    objective(pairs, track, 0.0, np.zeros(3)), objective(pairs, track, c, r))


def sweep_offset(pairs: Sequence[Pair], track: Track, offsets_s: F64,
                 rounds: int = 3) -> tuple[float, float, float]:
    """The clock offset (s) minimising the pair objective at the recorded rotation: a grid
    `offsets_s`, parabola-refined, then `rounds` - 1 finer grids (half as wide) about it;
    (offset, objective at offset 0, objective at the offset)."""
    c = 0.0
    for _ in range(rounds):
        ys = np.array([objective(pairs, track, o, np.zeros(3)) for o in offsets_s])
        c = _refine(offsets_s, ys)
        offsets_s = c + (offsets_s - offsets_s.mean()) * 0.5
    return (c, objective(pairs, track, 0.0, np.zeros(3)),
            objective(pairs, track, c, np.zeros(3)))
