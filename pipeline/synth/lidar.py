"""A 32-ring Hesai-XT32-like spinning LiDAR: per-point timestamps, noise, dropouts, undistortion.

A sweep fires `cols` azimuth columns of 32 rings (elevation -16..+15 deg, ring 0 lowest) over one
rotation period, counter-clockwise from the +x axis of `hesai_lidar`. Each column is cast from
the sensor pose at its own firing time (the body moves during the sweep). Ranges get Gaussian
noise; misses, out-of-range returns and random dropouts are removed. The kept points are then
motion-compensated into the LiDAR frame at the sweep's header stamp, which is the stamp of the
first kept point (as the GrandTour `points_undistorted` topic), or the last one for a
`header`-relative time convention (offsets <= 0). Points keep their true firing time in the
spec's time convention (`schemas.time_conventions.from_ns`; by default `timestamp` float64
absolute seconds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.poses import invert_T
from pipeline.synth.scene import Raycaster
from pipeline.synth.texture import intensity
from pipeline.synth.trajectory import Trajectory
from pipeline.synth.variants import LidarSpec, layout_dtype
from schemas.time_conventions import from_ns

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
    """One simulated sweep: header stamp (ns, = first kept point), packed points (n,) in the
    variant's layout (HESAI_DTYPE by default) in the LiDAR frame at the header stamp, the last
    point's stamp (ns), and how many of the points are written missing returns."""

    stamp_ns: int
    points: npt.NDArray[np.void]
    t_end_ns: int
    n_invalid: int = 0


GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
ROSETTE_HALF_ANGLE = np.deg2rad(35.0)
FORWARD_L = np.array([0.0, -1.0, 0.0])
"""The robot's forward axis in the LiDAR frame of the default rig (mounted turned 90 deg)."""


def beam_dirs(spec: LidarSpec, cols: int, sweep: int = 0) -> F64:
    """Unit directions (cols, B, 3) in the LiDAR frame, column-major firing order.

    spin: column c at azimuth 2 pi c / cols (counter-clockwise from +x), beam b at its
    elevation. livox: a rosette about FORWARD_L (radius |sin| of one frequency, angle of
    another), shifted every sweep by the golden ratio so sweeps never repeat.
    """
    B = spec.beams
    if spec.pattern == "spin":
        az = 2 * np.pi * np.arange(cols) / cols
        el = np.deg2rad(np.asarray(spec.elevations_deg))
        ce, se = np.cos(el)[None, :], np.sin(el)[None, :]
        return np.stack([ce * np.cos(az)[:, None], ce * np.sin(az)[:, None],
                         np.broadcast_to(se, (cols, B))], axis=-1)  # fmt: skip
    u = (np.arange(cols * B) + 0.5) / (cols * B) + (sweep * GOLDEN) % 1.0
    rho = ROSETTE_HALF_ANGLE * np.abs(np.sin(np.pi * 37.3 * u))
    theta = 2 * np.pi * 11.7 * u
    e1, e2 = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    d = (np.cos(rho)[:, None] * FORWARD_L
         + np.sin(rho)[:, None] * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2))
    dirs: npt.NDArray[np.float64] = d.reshape(cols, B, 3)
    return dirs


T_FIRST_SECOND = np.array([[-1.0, 0.0, 0.0, 0.25], [0.0, -np.cos(0.2), -np.sin(0.2), 0.0],
                           [0.0, -np.sin(0.2), np.cos(0.2), -0.12], [0.0, 0.0, 0.0, 1.0]])
"""T_first_second of a merged cloud's second sensor: turned 180 deg, tilted 11.5 deg, offset."""


@dataclass(frozen=True)
class _Cast:
    """One sensor's rotation: every beam's world origin and direction (M, 3), time (M,) ns,
    range (M,) m, kept mask (M,), material (M,), surface normal (M, 3), beam index (M,)."""

    o_w: F64
    d_w: F64
    t_ns: npt.NDArray[np.int64]
    r: F64
    keep: npt.NDArray[np.bool_]
    material: npt.NDArray[np.int64]
    normal: F64
    beam: npt.NDArray[np.int64]


def _cast(rc: Raycaster, traj: Trajectory, T_base_lidar: F64, model: LidarModel,
          spec: LidarSpec, col_ns: npt.NDArray[np.int64], t0_ns: int, sweep: int,
          rng: np.random.Generator) -> _Cast:  # fmt: skip
    """Cast every beam of one rotation from the sensor pose at its column's firing time."""
    B = spec.beams
    T_odom_lidar = traj.poses((col_ns - t0_ns) / 1e9) @ T_base_lidar  # (cols, 4, 4)
    d_l = beam_dirs(spec, col_ns.size, sweep)
    d_w = np.einsum("cij,crj->cri", T_odom_lidar[:, :3, :3], d_l).reshape(-1, 3)
    o_w = np.repeat(T_odom_lidar[:, :3, 3], B, axis=0)
    hits = rc.cast(o_w.astype(np.float32), d_w.astype(np.float32))
    r = hits.t.astype(np.float64) + rng.normal(0.0, model.range_noise_m, hits.t.size)
    keep = (hits.material >= 0) & (r > MIN_RANGE_M) & (r < model.max_range_m)
    keep &= rng.random(r.size) >= model.dropout
    beam = np.tile(np.arange(B, dtype=np.int64), col_ns.size)
    return _Cast(o_w, d_w, np.repeat(col_ns, B), r, keep, hits.material.astype(np.int64),
                 hits.normal.astype(np.float64), beam)  # fmt: skip


def simulate_sweep(rc: Raycaster, traj: Trajectory, T_base_lidar: F64, model: LidarModel,
                   start_ns: int, period_ns: int, t0_ns: int, rng: np.random.Generator,
                   spec: LidarSpec | None = None, sweep: int = 0) -> Sweep:  # fmt: skip
    """Fire one rotation starting at `start_ns` (absolute ns); t0_ns is the trajectory origin.

    `spec` (default: the Hesai XT32) sets beams, ring numbers, scan pattern, point layout and
    missing-return convention; `sweep` (the sweep number) moves a non-repetitive pattern.
    """
    spec = spec or LidarSpec()
    cols = max(1, model.cols * RINGS // spec.beams)
    col_ns = start_ns + (np.arange(cols, dtype=np.int64) * period_ns) // cols  # (cols,)
    casts = [_cast(rc, traj, T_base_lidar, model, spec, col_ns, t0_ns, sweep, rng)]
    if spec.merged:
        casts.append(_cast(rc, traj, T_base_lidar @ T_FIRST_SECOND, model, spec, col_ns, t0_ns,
                           sweep, rng))  # fmt: skip
    dtype = layout_dtype(spec.layout, spec.time)
    kept_t = [c.t_ns[c.keep] for c in casts if c.keep.any()]
    if not kept_t:
        return Sweep(int(start_ns), np.zeros(0, dtype=dtype), int(start_ns))
    if spec.time_convention.reference == "header":  # stamped at the sweep's end
        stamp_ns = int(max(int(t.max()) for t in kept_t))
    else:  # the first kept point
        stamp_ns = int(min(int(t.min()) for t in kept_t))
    T_h_inv = invert_T(traj.poses([(stamp_ns - t0_ns) / 1e9])[0] @ T_base_lidar)
    parts = [_points(c, T_h_inv, spec, dtype, stamp_ns) for c in casts]
    pts = np.zeros(sum(p.size for p, _ in parts), dtype=dtype)  # keeps the driver's padding
    pts[:] = np.concatenate([p for p, _ in parts]) if len(parts) > 1 else parts[0][0]
    times = np.concatenate([t for _, t in parts])
    if spec.merged:  # one cloud in time order, as a merging node writes it
        order = np.argsort(times, kind="stable")
        pts, times = pts[order], times[order]
    n_invalid = int(sum(int((~c.keep).sum()) for c in casts)) if spec.invalid else 0
    written = times[_valid(pts)] if spec.invalid else times
    return Sweep(stamp_ns, pts, int(written.max()), n_invalid)


def _valid(pts: npt.NDArray[np.void]) -> npt.NDArray[np.bool_]:
    """Points with finite, not all-zero coordinates."""
    x, y, z = (pts[c].astype(np.float64) for c in ("x", "y", "z"))
    ok: npt.NDArray[np.bool_] = (np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
                                 & ~((x == 0) & (y == 0) & (z == 0)))
    return ok


def _points(c: _Cast, T_h_inv: F64, spec: LidarSpec, dtype: np.dtype[np.void],
            stamp_ns: int) -> tuple[npt.NDArray[np.void], npt.NDArray[np.int64]]:  # fmt: skip
    """The packed points of one cast and their exact times (ns): kept returns
    motion-compensated into the LiDAR frame at the header stamp (T_h_inv = T_lidar_odom
    there); missed beams written as `spec.invalid` (or left out)."""
    idx = np.arange(c.keep.size) if spec.invalid else np.flatnonzero(c.keep)
    kept = c.keep[idx]
    p_w = c.o_w[idx] + c.d_w[idx] * c.r[idx, None]
    p_l = p_w @ T_h_inv[:3, :3].T + T_h_inv[:3, 3]
    pts = np.zeros(idx.size, dtype=dtype)
    xyz = np.where(kept[:, None], p_l, np.asarray(INVALID_XYZ.get(spec.invalid or "", [0.0] * 3)))
    pts["x"], pts["y"], pts["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    cos_inc = np.einsum("ni,ni->n", c.normal[idx], c.d_w[idx])
    mat = np.where(kept, c.material[idx], 0)
    pts["intensity"] = np.where(kept, intensity(mat, cos_inc.astype(np.float32)), 0.0)
    names = dtype.names or ()
    beam = c.beam[idx]
    if "ring" in names:
        pts["ring"] = np.asarray(spec.ring_ids, dtype=np.uint16)[beam]
    if "line" in names:
        pts["line"] = beam % 6
    t_ns = c.t_ns[idx]
    conv = spec.time_convention
    pts[conv.field] = from_ns(t_ns, stamp_ns, conv)
    return pts, t_ns


INVALID_XYZ = {"nan": [np.nan] * 3, "x_nan": [np.nan, 0.0, 0.0], "zero": [0.0] * 3,
               "posinf": [np.inf] * 3}  # fmt: skip
"""(x, y, z) a driver writes for a missed beam, by convention."""

