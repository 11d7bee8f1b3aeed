"""The LiDAR plausibility checks: clean spinning sweeps pass, a flipped high byte is caught."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.checks.sweep_checks import (
    SweepPoints,
    group_medians,
    limit_problem,
    point_range,
    ring_problem,
    rotation_problem,
    rotation_rate,
    sweep_problem,
)
from pipeline.synth.lidar import HESAI_DTYPE
from schemas.config import ChecksConfig

LIM = ChecksConfig()
ELEVATION = np.arange(-16.0, 16.0)  # XT32-like rings, ring 0 lowest
T0 = 1_717_000_000.0  # header stamp, s (the Hesai time field holds absolute seconds)


def spin(seed: int = 0, cols: int = 90, direction: float = 1.0, near: float = 5.0,
         far: float = 40.0) -> np.ndarray:  # fmt: skip
    """A packed sweep (HESAI_DTYPE) of a sensor turning once in 0.1 s from T0."""
    rng = np.random.default_rng(seed)
    k = np.repeat(np.arange(cols), ELEVATION.size)
    ring = np.tile(np.arange(ELEVATION.size), cols)
    az = direction * 2 * np.pi * k / cols
    el = np.deg2rad(ELEVATION[ring] + rng.normal(0, 0.05, k.size))
    r = rng.uniform(near, far, k.size)
    pts = np.zeros(k.size, dtype=HESAI_DTYPE)
    pts["x"], pts["y"] = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az)
    pts["z"], pts["ring"] = r * np.sin(el), ring
    pts["intensity"] = rng.uniform(0, 255, k.size)
    pts["timestamp"] = T0 + 0.1 * k / cols + rng.normal(0, 2e-6, k.size)
    return pts


def points(pts: np.ndarray) -> SweepPoints:
    """SweepPoints of a packed sweep (times made relative to the header stamp T0)."""
    xyz = np.stack([pts[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
    return SweepPoints(xyz, pts["timestamp"].astype(np.float64) - T0,
                       pts["intensity"].astype(np.float64), pts["ring"].astype(np.int64))


@pytest.mark.parametrize("direction", [1.0, -1.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_sweeps_pass(seed: int, direction: float) -> None:
    assert sweep_problem(points(spin(seed, direction=direction, near=0.5)), LIM) is None


def test_rotation_rate_found_either_way() -> None:
    for direction in (1.0, -1.0):
        p = points(spin(direction=direction))
        az = np.arctan2(p.xyz[:, 1], p.xyz[:, 0])
        assert p.t_s is not None
        rate = rotation_rate(az, p.t_s)
        assert rate == pytest.approx(direction * 2 * np.pi / 0.1, rel=0.02)


def test_limits_name_the_point() -> None:
    pts = spin()
    pts["x"][7] = 1e4
    found = limit_problem(points(pts), LIM)
    assert found and "first point 7" in found and "range" in found


def _flip(pts: np.ndarray, index: int, field: str, byte: int, xor: int) -> np.ndarray:
    """A copy of the packed sweep with one byte of one point's field XORed."""
    out = pts.copy()
    raw = out.view(np.uint8).reshape(out.size, HESAI_DTYPE.itemsize)
    raw[index, HESAI_DTYPE.fields[field][1] + byte] ^= xor
    return out


@settings(max_examples=150, deadline=None, derandomize=True)
@given(seed=st.integers(0, 5), index=st.integers(0, 90 * 32 - 1),
       field=st.sampled_from(["x", "y", "z", "timestamp", "intensity", "ring"]),
       xor=st.integers(1, 255), time_byte=st.integers(2, 7))  # fmt: skip
def test_high_byte_flip_is_caught(seed: int, index: int, field: str, xor: int,
                                  time_byte: int) -> None:  # fmt: skip
    """A flip in the sign/exponent byte of a coordinate that matters for the point's direction,
    in bytes 2-7 of its absolute float64 time (>= 15 ms), in intensity's sign or in the
    ring's high byte is caught (before the checks: nothing was)."""
    pts = spin(seed)
    byte = {"timestamp": time_byte, "ring": 1}.get(field, 3)
    p = pts[index]
    rho = float(np.hypot(p["x"], p["y"]))
    if field in ("x", "y") and abs(float(p[field])) < 0.5 * rho:
        return  # a small coordinate scaled or negated barely turns the point
    if field == "z" and (xor & 0x80 == 0 or abs(float(p["z"])) < 0.1 * rho):
        return  # z scaled down toward 0 stays within a ring's tolerance near the horizon
    if field == "intensity" and (xor & 0x80 == 0 or float(p["intensity"]) == 0.0):
        return  # scaled within 0-255 it is a plausible intensity (-0.0 is 0.0)
    assert sweep_problem(points(_flip(pts, index, field, byte, xor)), LIM), (field, xor)


def test_checks_off() -> None:
    pts = spin()
    pts["x"][3] = 1e4
    assert sweep_problem(points(pts), ChecksConfig(enabled=False)) is None


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 5), st.floats(-1e3, 1e3)), min_size=1, max_size=80))
def test_group_medians_equal_numpy_per_group(pairs: list[tuple[int, float]]) -> None:
    groups = np.array([g for g, _ in pairs], dtype=np.intp)
    values = np.array([v for _, v in pairs])
    got = group_medians(values, groups, 7)
    for k in range(7):
        want = np.median(values[groups == k]) if (groups == k).any() else np.nan
        assert np.array_equal(got[k], want, equal_nan=True), (k, got[k], want)


# The checks compute the slack of a point only where it can matter, and share sorts; the
# verdicts and their lines must be those of the plain full-array formulation below.


def _ref_wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _ref_first(bad: np.ndarray, what: str, values: np.ndarray, n: int) -> str | None:
    idx = np.flatnonzero(bad)
    if idx.size == 0:
        return None
    i = idx[0]
    return f"{idx.size} of {n} points implausible, first point {i}: {what} {values[i]:.6g}"


def _ref_ring(p: SweepPoints, lim: ChecksConfig) -> str | None:
    assert p.ring is not None
    x, y, z = p.xyz[:, 0], p.xyz[:, 1], p.xyz[:, 2]
    rho = np.hypot(x, y)
    el = np.arctan2(z, rho)
    _, inverse, counts = np.unique(p.ring, return_inverse=True, return_counts=True)
    sub = slice(None, None, max(1, el.size // 4096))
    med = np.array([np.median(el[sub][inverse[sub] == g]) if (inverse[sub] == g).any()
                    else np.nan for g in range(counts.size)])  # fmt: skip
    dev = np.abs(el - med[inverse])
    tol = np.deg2rad(lim.ring_elevation_tol_deg) + np.arctan2(
        lim.sweep_motion_m, np.maximum(np.hypot(rho, z), 1e-6))
    with np.errstate(invalid="ignore"):
        bad = (dev > tol) & (counts[inverse] >= 5)
    return _ref_first(bad, "elevation off its ring's median by (deg)", np.rad2deg(dev),
                      p.xyz.shape[0])  # fmt: skip


def _ref_rotation(p: SweepPoints, lim: ChecksConfig) -> str | None:
    assert p.t_s is not None
    az = np.arctan2(p.xyz[:, 1], p.xyz[:, 0])
    sub = slice(None, None, max(1, az.size // 4096))
    fin = np.isfinite(p.t_s[sub])
    a_s, t_s = az[sub][fin], p.t_s[sub][fin]
    order = np.argsort(t_s, kind="stable")
    t, a = t_s[order], a_s[order]
    if np.unique(t).size < 16:
        return None
    k = max(1, t.size // 16)
    step = t[k:] - t[:-k]
    rate = float(np.median(_ref_wrap(a[k:] - a[:-k])[step > 0] / step[step > 0]))
    ph = a_s - rate * t_s
    centre = float(np.arctan2(np.sin(ph).sum(), np.cos(ph).sum()))
    tol = np.deg2rad(lim.azimuth_tol_deg) + np.arctan2(
        lim.sweep_motion_m, np.maximum(np.linalg.norm(p.xyz, axis=1), 1e-6))
    with np.errstate(invalid="ignore"):
        dev = np.abs(_ref_wrap(az - rate * p.t_s - centre))
        off = dev > tol
    return _ref_first(off, f"azimuth off the rotation ({np.rad2deg(rate):.0f} deg/s) by (deg)",
                      np.rad2deg(dev), p.xyz.shape[0])  # fmt: skip


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 5), flips=st.lists(st.tuples(
           st.integers(0, 90 * 32 - 1), st.sampled_from(["x", "y", "z", "timestamp", "ring"]),
           st.integers(0, 7), st.integers(1, 255)), max_size=6),
       motion=st.sampled_from([0.0, 0.5, 5.0]), tol=st.sampled_from([0.05, 1.0, 10.0]),
       near=st.sampled_from([0.01, 0.5, 5.0]))  # fmt: skip
def test_checks_equal_full_array_reference(seed: int, flips: list[tuple[int, str, int, int]],
                                           motion: float, tol: float, near: float) -> None:
    """Ring and rotation verdicts (and their lines) are those of the full-array formulation,
    on clean and damaged sweeps, tight and loose tolerances, still and moving sensors."""
    pts = spin(seed, near=near)
    for index, field, byte, xor in flips:
        pts = _flip(pts, index, field, byte if field != "ring" else byte % 2, xor)
    with np.errstate(all="ignore"):
        p = points(pts)
        lim = ChecksConfig(sweep_motion_m=motion, azimuth_tol_deg=tol, ring_elevation_tol_deg=tol)
        assert ring_problem(p, lim) == _ref_ring(p, lim)
        assert rotation_problem(p, lim) == _ref_rotation(p, lim)
        assert np.array_equal(point_range(p.xyz), np.linalg.norm(p.xyz, axis=1), equal_nan=True)
