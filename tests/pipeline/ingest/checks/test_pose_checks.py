"""Odometry plausibility: unit quaternions, and the jump filter keeps good neighbours."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.checks.pose_checks import JumpFilter, PoseVerdict, quat_norm_problem

HZ = 20


def walk(n: int, seed: int, speed: float = 2.0) -> tuple[list[int], np.ndarray]:
    """Stamps (ns, 20 Hz with jitter) and positions (n, 3) of a robot at <= `speed` m/s."""
    rng = np.random.default_rng(seed)
    dt = 1 / HZ + rng.uniform(-0.004, 0.004, n)
    stamps = (1_717_000_000 * 10**9 + np.cumsum(dt * 1e9)).astype(np.int64).tolist()
    heading = np.cumsum(rng.normal(0, 0.2, n))
    v = speed * rng.uniform(0, 1, n)
    step = np.stack([np.cos(heading), np.sin(heading), rng.normal(0, 0.05, n)], 1)
    step *= (v * dt)[:, None] / np.linalg.norm(step, axis=1, keepdims=True)
    return stamps, 100.0 + np.cumsum(step, axis=0) + rng.normal(0, 0.002, (n, 3))


def run(stamps: list[int], pos: np.ndarray, max_speed: float = 10.0) -> list[PoseVerdict]:
    """Every verdict of a jump filter over one stream, in order."""
    f = JumpFilter(max_speed)
    out = [v for s, p in zip(stamps, pos, strict=True) for v in f.push(s, p, s)]
    return out + f.flush()


@settings(max_examples=40, deadline=None, derandomize=True)
@given(n=st.integers(1, 60), seed=st.integers(0, 1000))
def test_clean_walk_is_kept_in_order(n: int, seed: int) -> None:
    stamps, pos = walk(n, seed)
    verdicts = run(stamps, pos)
    assert [v.item for v in verdicts] == stamps
    assert all(v.problem is None for v in verdicts)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(n=st.integers(5, 40), seed=st.integers(0, 1000), data=st.data())
def test_jumps_rejected_neighbours_kept(n: int, seed: int, data: st.DataObject) -> None:
    """One or two consecutive poses thrown >= 3 m away (anywhere, the ends too): exactly those
    are rejected (before the filter: every one was indexed). At 10 m/s and 20 Hz a jump must
    exceed about 1 m (the speed limit over two frame periods) to be seen."""
    stamps, pos = walk(n, seed)
    first = data.draw(st.integers(0, n - 1))
    bad = list(range(first, min(n, first + data.draw(st.integers(1, 2)))))
    jumps = data.draw(st.permutations([3.0, -5.0, 50.0, 1e5]))  # two bad poses disagree too
    for i, jump in zip(bad, jumps, strict=False):
        pos[i] += jump * np.array([1.0, 0.3, 0.0])
    verdicts = run(stamps, pos)
    assert [i for i, v in enumerate(verdicts) if v.problem] == bad
    assert all(f"{stamps[i]} " not in (v.problem or "") for i, v in enumerate(verdicts))


def _flip_f64(value: float, byte: int, xor: int) -> float:
    """`value` with one byte of its little-endian float64 XORed."""
    raw = bytearray(struct.pack("<d", value))
    raw[byte] ^= xor
    return float(struct.unpack("<d", bytes(raw))[0])


@settings(max_examples=100, deadline=None, derandomize=True)
@given(q=st.lists(st.floats(-1, 1), min_size=4, max_size=4), k=st.integers(0, 3),
       byte=st.integers(5, 7), xor=st.integers(1, 255))  # fmt: skip
def test_quaternion_flip_caught(q: list[float], k: int, byte: int, xor: int) -> None:
    """A unit quaternion passes; a flip in the top 3 bytes of a component >= 0.3 does not."""
    quat = np.array(q, dtype=np.float64)
    if np.linalg.norm(quat) < 0.1:
        return
    quat /= np.linalg.norm(quat)
    assert quat_norm_problem(quat, 1e-6) is None
    if abs(quat[k]) < 0.3:
        return
    quat[k] = _flip_f64(float(quat[k]), byte, xor)
    assert not np.isfinite(quat).all() or quat_norm_problem(quat, 1e-6)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(n=st.integers(1, 40), seed=st.integers(0, 1000), data=st.data())
def test_unjudged_poses_change_no_other_verdict(n: int, seed: int, data: st.DataObject) -> None:
    """Poses pushed unjudged (a checksum vouches for them) come out in the same order with no
    problem; every judged pose gets the verdict it gets when all are judged."""
    stamps, pos = walk(n, seed)
    bad = data.draw(st.sets(st.integers(0, n - 1), max_size=3))
    for k in bad:
        pos[k] += 50.0
    skip = data.draw(st.sets(st.integers(0, n - 1)))
    all_judged = run(stamps, pos)
    f = JumpFilter(10.0)
    some = [v for i, (s, p) in enumerate(zip(stamps, pos, strict=True))
            for v in f.push(s, p, s, judge=i not in skip)] + f.flush()  # fmt: skip
    assert [v.item for v in some] == [v.item for v in all_judged] == stamps
    for i, (a, b) in enumerate(zip(all_judged, some, strict=True)):
        assert b.problem == (None if i in skip else a.problem)
