"""A 32-ring Hesai-XT32-like spinning LiDAR: per-point timestamps, noise, dropouts, undistortion.

A sweep fires `cols` azimuth columns of 32 rings (elevation -16..+15 deg, ring 0 lowest) over one
rotation period, counter-clockwise from the +x axis of `hesai_lidar`. Each column is cast from
the sensor pose at its own firing time (the body moves during the sweep). Ranges get Gaussian
noise; misses, out-of-range returns and random dropouts are removed. The kept points are then
motion-compensated into the LiDAR frame at the sweep's header stamp, which is the stamp of the
first kept point (as the GrandTour `points_undistorted` topic). Points keep their true firing
time in the `timestamp` field (float64 absolute seconds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.poses import invert_T
from pipeline.synth.scene import Raycaster
from pipeline.synth.texture import intensity
from pipeline.synth.trajectory import Trajectory

F64 = npt.NDArray[np.float64]

RINGS = 32
ELEVATION_DEG = np.arange(-16.0, 16.0, 1.0)  # (32,), ring index = position in this array
MIN_RANGE_M = 0.3
# The real driver's layout: float64 timestamp at offset 18 (unaligned), point_step 26.
HESAI_DTYPE = np.dtype(
    {
        "names": ["x", "y", "z", "intensity", "ring", "timestamp"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f8"],
        "offsets": [0, 4, 8, 12, 16, 18],
        "itemsize": 26,
    }
)
# (name, offset, PointField datatype): FLOAT32 = 7, UINT16 = 4, FLOAT64 = 8
HESAI_FIELDS = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7), ("ring", 16, 4),
                ("timestamp", 18, 8)]  # fmt: skip


@dataclass(frozen=True)
class LidarModel:
    """Sweep geometry and noise: columns per sweep, range noise sigma (m), dropout probability,
    maximum range (m)."""

    cols: int
    range_noise_m: float
    dropout: float
    max_range_m: float

    @staticmethod
    def for_points(points_per_sweep: int, range_noise_m: float, dropout: float,
                   max_range_m: float) -> LidarModel:  # fmt: skip
        """Columns so that cols * 32 <= points_per_sweep (at least one column)."""
        return LidarModel(max(1, points_per_sweep // RINGS), range_noise_m, dropout, max_range_m)

    def ring_dirs(self) -> F64:
        """Unit directions (cols, 32, 3) in the LiDAR frame, column-major firing order."""
        az = 2 * np.pi * np.arange(self.cols) / self.cols
        el = np.deg2rad(ELEVATION_DEG)
        ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
        return np.stack([ce * np.cos(az)[:, None], ce * np.sin(az)[:, None],
                         np.broadcast_to(se, (self.cols, RINGS))], axis=-1)  # fmt: skip


@dataclass(frozen=True)
class Sweep:
    """One simulated sweep: header stamp (ns, = first kept point), packed points (n,) HESAI_DTYPE
    in the LiDAR frame at the header stamp, and the last point's stamp (ns)."""

    stamp_ns: int
    points: npt.NDArray[np.void]
    t_end_ns: int


def simulate_sweep(rc: Raycaster, traj: Trajectory, T_base_lidar: F64, model: LidarModel,
                   start_ns: int, period_ns: int, t0_ns: int,
                   rng: np.random.Generator) -> Sweep:  # fmt: skip
    """Fire one rotation starting at `start_ns` (absolute ns); t0_ns is the trajectory origin."""
    cols = model.cols
    col_ns = start_ns + (np.arange(cols, dtype=np.int64) * period_ns) // cols  # (cols,)
    T_odom_lidar = traj.poses((col_ns - t0_ns) / 1e9) @ T_base_lidar  # (cols, 4, 4)
    d_l = model.ring_dirs()  # (cols, 32, 3)
    d_w = np.einsum("cij,crj->cri", T_odom_lidar[:, :3, :3], d_l).reshape(-1, 3)
    o_w = np.repeat(T_odom_lidar[:, :3, 3], RINGS, axis=0)
    hits = rc.cast(o_w.astype(np.float32), d_w.astype(np.float32))
    r = hits.t.astype(np.float64) + rng.normal(0.0, model.range_noise_m, hits.t.size)
    keep = (hits.material >= 0) & (r > MIN_RANGE_M) & (r < model.max_range_m)
    keep &= rng.random(r.size) >= model.dropout
    idx = np.flatnonzero(keep)
    t_ns = np.repeat(col_ns, RINGS)[idx]
    if idx.size == 0:
        return Sweep(int(start_ns), np.zeros(0, dtype=HESAI_DTYPE), int(start_ns))
    stamp_ns = int(t_ns[0])  # firing order is time order: the first kept point
    p_w = o_w[idx] + d_w[idx] * r[idx, None]
    T_h = traj.poses([(stamp_ns - t0_ns) / 1e9])[0] @ T_base_lidar
    p_l = p_w @ invert_T(T_h)[:3, :3].T + invert_T(T_h)[:3, 3]
    pts = np.zeros(idx.size, dtype=HESAI_DTYPE)
    pts["x"], pts["y"], pts["z"] = p_l[:, 0], p_l[:, 1], p_l[:, 2]
    cos_inc = np.einsum("ni,ni->n", hits.normal[idx].astype(np.float64), d_w[idx])
    pts["intensity"] = intensity(hits.material[idx], cos_inc.astype(np.float32))
    pts["ring"] = np.tile(np.arange(RINGS, dtype=np.uint16), cols)[idx]
    pts["timestamp"] = t_ns / 1e9
    return Sweep(stamp_ns, pts, int(t_ns[-1]))
