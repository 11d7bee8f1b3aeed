"""Plausibility of one decoded LiDAR sweep (pure numpy): is any point impossible for the sensor?

A ROS1 bag has no per-message checksum, so a flipped byte inside a PointCloud2 payload decodes
to a finite point. Such a point is caught when it breaks what a spinning LiDAR guarantees:

- limits: range within `max_range_m`, intensity in [0, `max_intensity`], ring <= `max_ring`,
  point time within `max_sweep_s` of the header stamp (a time the topic's convention cannot
  read, NaN, is implausible here: a check, fitted to the stream, never `corrupt`);
- ring structure: every ring has one elevation angle, so each point's elevation lies within
  `ring_elevation_tol_deg` of its ring's median elevation in this sweep (a flipped z or ring);
- rotation: the azimuth turns at a constant rate, so azimuth minus rate x time is the same for
  every point up to `azimuth_tol_deg` (a flipped x, y or time). The rate and its sign are
  estimated from the sweep itself (median over consecutive firing times), no calibration.

Both angle tolerances widen by atan(`sweep_motion_m` / range): an undistorted cloud is
motion-compensated, so near points move in angle with the sensor's motion. Checks whose fields
the cloud lacks are skipped. Not caught (no check can): a flip in the low mantissa bits of a
coordinate (below ~1 % of it: inside the sensor's noise) or of the intensity.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from schemas.config import ChecksConfig

F64 = npt.NDArray[np.float64]
MIN_RING_POINTS = 5
"""A ring's median elevation is trusted when it has at least this many points."""
MIN_ROTATION_POINTS = 16
"""The rotation check needs this many distinct firing times."""
REFERENCE_POINTS = 4096
"""Ring elevations and the rotation rate are estimated from about this many points (every
k-th); every point is then checked against them."""


def _every(n: int) -> slice:
    """Every k-th of n points, about REFERENCE_POINTS of them."""
    return slice(None, None, max(1, n // REFERENCE_POINTS))


@dataclass(frozen=True)
class SweepPoints:
    """Kept points of one sweep: xyz (N, 3) m, t_s (N,) s from the header stamp or None,
    intensity (N,) or None, ring (N,) int or None."""

    xyz: F64
    t_s: F64 | None = None
    intensity: F64 | None = None
    ring: npt.NDArray[np.int64] | None = None


def _first(bad: npt.NDArray[np.bool_], what: str, values: F64, n: int) -> str | None:
    """One line naming the first offending point, or None when there is none."""
    idx = np.flatnonzero(bad)
    if idx.size == 0:
        return None
    i = int(idx[0])
    return f"{idx.size} of {n} points implausible, first point {i}: {what} {values[i]:.6g}"


def _first_of(idx: npt.NDArray[np.intp], what: str, value: float, n: int) -> str | None:
    """`_first` from the offending points' indices (ascending) and the first one's value."""
    if idx.size == 0:
        return None
    return (f"{idx.size} of {n} points implausible, first point {int(idx[0])}: {what} "
            f"{value:.6g}")  # fmt: skip


def _wrap(a: F64) -> F64:
    """Angles (rad) wrapped to [-pi, pi); equal to (a + pi) % (2 pi) - pi element for element.

    The remainder (the slow part) is taken only where a + pi lies outside [0, 2 pi): inside,
    it is a + pi itself (fmod is exact there)."""
    y = np.asarray(a + np.pi, dtype=np.float64)
    out = y.copy()
    outside = (y < 0) | (y >= 2 * np.pi)  # NaN: neither, stays NaN
    out[outside] = np.remainder(y[outside], 2 * np.pi)
    out -= np.pi
    return out


def _slack(r: F64, motion_m: float) -> F64:
    """Angle (rad) a point at range r may move by while the sensor moves motion_m."""
    return np.arctan2(motion_m, np.maximum(r, 1e-6))


def _beyond_tolerance(dev: F64, tol_rad: float, r_of: Callable[[npt.NDArray[np.intp]], F64],
                      motion_m: float) -> npt.NDArray[np.intp]:  # fmt: skip
    """Indices (ascending) of the points with dev > tol_rad + _slack(range, motion_m).

    The slack is >= 0 (motion_m >= 0), so only points with dev > tol_rad can exceed it: the
    range and the slack are computed for those alone (`r_of(indices)`: their ranges). NaN dev
    is never beyond."""
    with np.errstate(invalid="ignore"):
        cand = np.flatnonzero(dev > tol_rad) if motion_m >= 0 else np.arange(dev.size)
    if cand.size == 0:
        return cand
    tol = tol_rad + _slack(r_of(cand), motion_m)
    return cand[dev[cand] > tol]


def point_range(xyz: F64) -> F64:
    """(N,) distance (m) of each point (N, 3) from the sensor; equal to
    np.linalg.norm(xyz, axis=1) (the same sum, x^2 + y^2 + z^2 in that order), faster."""
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return np.asarray(np.sqrt(x * x + y * y + z * z), dtype=np.float64)


def limit_problem(p: SweepPoints, lim: ChecksConfig) -> str | None:
    """The first point beyond a sensor limit (range, intensity, ring, time), or None."""
    n = p.xyz.shape[0]
    r = point_range(p.xyz)
    checks = [(r > lim.max_range_m, f"range (m) beyond {lim.max_range_m:g}", r)]
    if p.intensity is not None:
        bad = ~((p.intensity >= 0) & (p.intensity <= lim.max_intensity))
        checks.append((bad, f"intensity outside 0-{lim.max_intensity:g}", p.intensity))
    if p.ring is not None:
        checks.append((p.ring > lim.max_ring, f"ring above {lim.max_ring}",
                       p.ring.astype(np.float64)))  # fmt: skip
    if p.t_s is not None:
        with np.errstate(invalid="ignore"):
            bad = ~(np.abs(p.t_s) <= lim.max_sweep_s)  # NaN: a time that could not be read
        checks.append((bad, f"time (s from the header stamp) beyond {lim.max_sweep_s:g}", p.t_s))
    for bad, what, values in checks:
        found = _first(bad, what, values, n)
        if found:
            return found
    return None


def group_medians(values: F64, groups: npt.NDArray[np.intp], n_groups: int) -> F64:
    """(n_groups,) median of `values` (N,) per group id in [0, n_groups) (N,), NaN for an
    empty group; one sort instead of a median per group (equal to np.median per group)."""
    by_value = np.argsort(values)  # ties hold equal values: their order does not matter
    g = groups[by_value]
    g = g.astype(np.uint16) if n_groups <= 1 << 16 else g  # 16-bit: a radix sort
    v = values[by_value[np.argsort(g, kind="stable")]]  # by group, by value within it
    counts = np.bincount(groups, minlength=n_groups)
    start = np.cumsum(counts) - counts
    has = counts > 0
    med = np.full(n_groups, np.nan)
    lo, hi = start + (counts - 1) // 2, start + counts // 2
    med[has] = (v[lo[has]] + v[hi[has]]) / 2
    return med


def _ring_groups(ring: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """(group id (N,), points per group (G,)) of ring numbers: the ring itself when rings are
    small non-negative numbers (no sort), else their rank among the distinct rings."""
    if ring.size and int(ring.min()) >= 0 and int(ring.max()) < 1 << 16:
        groups = ring.astype(np.intp)
        return groups, np.bincount(groups)
    _, inverse, counts = np.unique(ring, return_inverse=True, return_counts=True)
    return inverse.astype(np.intp), counts.astype(np.intp)


def ring_problem(p: SweepPoints, lim: ChecksConfig) -> str | None:
    """The first point whose elevation does not match its ring's, or None (no ring field)."""
    if p.ring is None or p.xyz.shape[0] == 0:
        return None
    x, y, z = p.xyz[:, 0], p.xyz[:, 1], p.xyz[:, 2]
    rho = np.hypot(x, y)
    el = np.arctan2(z, rho)
    inverse, counts = _ring_groups(p.ring)
    sub = _every(el.size)
    el_sub, inv_sub = el[sub], inverse[sub]
    median = group_medians(el_sub, inv_sub, counts.size)
    dev = np.abs(el - median[inverse])  # NaN: a ring absent from the reference points

    def r_of(i: npt.NDArray[np.intp]) -> F64:
        return np.asarray(np.hypot(rho[i], z[i]), dtype=np.float64)

    far = _beyond_tolerance(dev, float(np.deg2rad(lim.ring_elevation_tol_deg)), r_of,
                            lim.sweep_motion_m)  # fmt: skip
    bad = far[counts[inverse[far]] >= MIN_RING_POINTS]
    return _first_of(bad, "elevation off its ring's median by (deg)",
                     float(np.rad2deg(dev[bad[0]])) if bad.size else 0.0,
                     p.xyz.shape[0])  # fmt: skip


def rotation_rate(az: F64, t_s: F64) -> float | None:
    """Signed azimuth rate (rad/s) of a spinning sensor, or None with too few firing times.

    Points sorted by time are paired with the point n/16 later (about 22 degrees of a full
    rotation: no wrap ambiguity, and not dominated by the microsecond steps within one firing
    column); the median of their wrapped azimuth step over their time step.
    """
    order = np.argsort(t_s, kind="stable")
    t, a = t_s[order], az[order]
    if _distinct_sorted(t) < MIN_ROTATION_POINTS:
        return None
    k = max(1, t.size // 16)
    step = t[k:] - t[:-k]
    ok = step > 0
    return float(np.median(_wrap(a[k:] - a[:-k])[ok] / step[ok]))


def _distinct_sorted(t: F64) -> int:
    """Number of distinct values of a sorted array without NaN (np.unique(t).size)."""
    return int(t.size and 1 + np.count_nonzero(t[1:] != t[:-1]))


def rotation_problem(p: SweepPoints, lim: ChecksConfig) -> str | None:
    """The first point whose azimuth is not where the rotation puts it at its time, or None."""
    if p.t_s is None or p.xyz.shape[0] == 0:
        return None
    az = np.arctan2(p.xyz[:, 1], p.xyz[:, 0])
    sub = _every(az.size)
    fin = np.isfinite(p.t_s[sub])  # an unreadable time is the limit check's
    rate = rotation_rate(az[sub][fin], p.t_s[sub][fin])
    if rate is None:
        return None
    ph_sub = az[sub][fin] - rate * p.t_s[sub][fin]
    centre = float(np.arctan2(np.sin(ph_sub).sum(), np.cos(ph_sub).sum()))  # circular mean
    with np.errstate(invalid="ignore"):
        dev = np.abs(_wrap(az - rate * p.t_s - centre))  # NaN time: never beyond
    off = _beyond_tolerance(dev, float(np.deg2rad(lim.azimuth_tol_deg)),
                            lambda i: point_range(p.xyz[i]), lim.sweep_motion_m)  # fmt: skip
    return _first_of(off, f"azimuth off the rotation ({np.rad2deg(rate):.0f} deg/s) by (deg)",
                     float(np.rad2deg(dev[off[0]])) if off.size else 0.0,
                     p.xyz.shape[0])  # fmt: skip


SWEEP_CHECKS = ("point_limits", "ring_elevation", "rotation")
"""Names of the sweep checks (`check_fit` records them per topic)."""


def sweep_problems(p: SweepPoints, lim: ChecksConfig,
                   active: Callable[[str], bool] = lambda _: True) -> dict[str, str | None]:
    """Verdict of every sweep check that applies to the cloud (ring: it has a ring field;
    rotation: a time field) and is `active`: None when plausible, else one line."""
    checks: list[tuple[str, Callable[[SweepPoints, ChecksConfig], str | None]]] = [
        ("point_limits", limit_problem)]
    if p.ring is not None:
        checks.append(("ring_elevation", ring_problem))
    if p.t_s is not None:
        checks.append(("rotation", rotation_problem))
    return {name: check(p, lim) for name, check in checks if active(name)}


def sweep_problem(p: SweepPoints, lim: ChecksConfig) -> str | None:
    """The first failed plausibility check of a sweep, in one line; None when it is plausible."""
    if not lim.enabled:
        return None
    return next((v for v in sweep_problems(p, lim).values() if v), None)
