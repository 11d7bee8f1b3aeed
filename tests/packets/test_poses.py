"""Pose math: inverse pairs, quaternion round trips, slerp (antipodal case), interpolation."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.poses import (
    compose,
    interpolate_poses,
    invert_T,
    lidar_to_camera,
    make_T,
    nearest_stamps,
    quat_to_rot,
    rot_to_quat,
    slerp,
)
from tests.strategies import rigid_transforms, unit_quaternions


def _angle(qa: np.ndarray, qb: np.ndarray) -> float:
    """Rotation angle between two quaternions (radians)."""
    return float(2 * np.arccos(np.clip(abs(np.dot(qa, qb)), 0, 1)))


@settings(max_examples=50, deadline=None)
@given(T=rigid_transforms())
def test_invert_is_inverse(T: np.ndarray) -> None:
    np.testing.assert_allclose(compose(T, invert_T(T)), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(invert_T(T), np.linalg.inv(T), atol=1e-12)


@settings(max_examples=80, deadline=None)
@given(q=unit_quaternions())
def test_quaternion_round_trip(q: np.ndarray) -> None:
    R = quat_to_rot(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    back = rot_to_quat(R)
    assert back[3] >= 0
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9  # q and -q: same rotation


@settings(max_examples=60, deadline=None)
@given(qa=unit_quaternions(), qb=unit_quaternions(), s=st.floats(0.0, 1.0))
def test_slerp_takes_the_short_arc_at_constant_speed(
    qa: np.ndarray, qb: np.ndarray, s: float
) -> None:
    total = _angle(qa, qb)
    q = slerp(qa, qb, s)
    assert abs(_angle(qa, q) - s * total) < 1e-6
    assert abs(_angle(q, qb) - (1 - s) * total) < 1e-6


def test_slerp_antipodal_quaternion_is_the_same_rotation() -> None:
    qa = np.array([0.0, 0.0, np.sin(0.1), np.cos(0.1)])  # 0.2 rad about z
    qb = -np.array([0.0, 0.0, np.sin(0.2), np.cos(0.2)])  # 0.4 rad, stored negated
    mid = slerp(qa, qb, 0.5)
    expected = np.array([0.0, 0.0, np.sin(0.15), np.cos(0.15)])
    np.testing.assert_allclose(quat_to_rot(mid), quat_to_rot(expected), atol=1e-12)
    # the naive (unflipped) interpolation would pass near the identity's antipode
    assert _angle(mid, expected) < 1e-9


def test_interpolation_exact_linear_and_no_extrapolation() -> None:
    base = 1_700_000_000_000_000_000
    stamps = base + np.array([0, 100_000_000, 200_000_000, 700_000_000], dtype=np.int64)
    pos = np.array([[0.0, 0, 0], [1, 0, 0], [2, 2, 0], [3, 2, 0]])
    yaw = np.array([0.0, 0.2, 0.4, 0.5])
    quats = np.array([[0, 0, np.sin(a / 2), np.cos(a / 2)] for a in yaw])
    query = base + np.array([-1, 0, 25_000_000, 150_000_000, 400_000_000, 700_000_001])
    out = interpolate_poses(stamps, pos, quats, query, max_gap_ns=250_000_000)
    assert out.ok.tolist() == [False, True, True, True, False, False]
    np.testing.assert_allclose(out.T[2, :3, 3], [0.25, 0, 0], atol=1e-12)
    np.testing.assert_allclose(out.T[3, :3, 3], [1.5, 1.0, 0], atol=1e-12)
    np.testing.assert_allclose(quat_to_rot(rot_to_quat(out.T[3, :3, :3])), out.T[3, :3, :3])
    assert abs(np.arctan2(out.T[3, 1, 0], out.T[3, 0, 0]) - 0.3) < 1e-12
    assert out.gap_ns[4] == 500_000_000
    np.testing.assert_array_equal(out.T[0], np.eye(4))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 10**12), min_size=1, max_size=30, unique=True),
       st.lists(st.integers(-(10**11), 2 * 10**12), min_size=1, max_size=20))  # fmt: skip
def test_nearest_stamps_matches_brute_force(stamps: list[int], query: list[int]) -> None:
    big = 1_700_000_000_000_000_000
    t = big + np.array(sorted(stamps), dtype=np.int64)
    q = big + np.array(query, dtype=np.int64)
    idx, dtau = nearest_stamps(q, t)
    for i, qi in enumerate(q):
        d = np.abs(t - qi)
        assert d[idx[i]] == d.min()
        assert idx[i] == int(np.flatnonzero(d == d.min())[0])  # tie -> earlier
        assert dtau[i] == (int(t[idx[i]]) - int(qi)) / 1e9


@settings(max_examples=30, deadline=None)
@given(a=rigid_transforms(), b=rigid_transforms(), c=rigid_transforms(), d=rigid_transforms())
def test_lidar_to_camera_chain_maps_points_consistently(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray
) -> None:
    """A LiDAR point goes to odom via the sweep pose, back via the image pose, into the camera."""
    T_base_cam, T_ob_img, T_ob_swp, T_base_lidar = a, b, c, d
    p = np.array([1.0, -2.0, 3.0, 1.0])
    p_odom = T_ob_swp @ T_base_lidar @ p
    p_cam = np.linalg.inv(T_base_cam) @ np.linalg.inv(T_ob_img) @ p_odom
    got = lidar_to_camera(T_base_cam, T_ob_img, T_ob_swp, T_base_lidar) @ p
    np.testing.assert_allclose(got, p_cam, atol=1e-9)


def test_make_T_batches() -> None:
    R = quat_to_rot(np.array([[0, 0, 0, 1.0], [1.0, 0, 0, 0]]))
    T = make_T(R, np.zeros((2, 3)))
    assert T.shape == (2, 4, 4)
    np.testing.assert_allclose(T[1, :3, :3], np.diag([1.0, -1, -1]))
