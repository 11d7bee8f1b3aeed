"""The LiDAR plausibility checks: clean spinning sweeps pass, a flipped high byte is caught."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.sweep_checks import (
    SweepPoints,
    group_medians,
    limit_problem,
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
