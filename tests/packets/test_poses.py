"""Pose math: inverse pairs, quaternion round trips, slerp (antipodal case), interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.poses import (
    compose,
    interpolate_poses,
    invert_T,
    lidar_to_camera,
    make_T,
    nearest_stamps,
    quat_normalize,
    quat_to_rot,
    rot_to_quat,
    slerp,
)
from schemas.errors import DataError
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


# --- interpolate_poses: boundaries, dtypes, refusals -------------------------------------------

_BASE = 1_700_000_000_000_000_000
_YAW_Q = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, np.sin(0.25), np.cos(0.25)]])  # 0, 0.5 rad


def test_interpolation_gap_bound_is_inclusive() -> None:
    stamps = _BASE + np.array([0, 100], dtype=np.int64)
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    at = interpolate_poses(stamps, pos, _YAW_Q, [_BASE + 30], max_gap_ns=100)
    below = interpolate_poses(stamps, pos, _YAW_Q, [_BASE + 30], max_gap_ns=99)
    assert at.ok.tolist() == [True] and at.gap_ns.tolist() == [100]
    assert below.ok.tolist() == [False] and below.gap_ns.tolist() == [100]
    np.testing.assert_array_equal(below.T[0], np.eye(4))
    np.testing.assert_allclose(at.T[0, :3, 3], [0.3, 0.0, 0.0], rtol=1e-15)


def test_interpolation_first_and_last_sample_are_exact_hits() -> None:
    """The first and last stamps are inside (inclusive); an exact hit has gap 0 and the sample's
    own pose, whatever the gap bound; one nanosecond outside is refused with gap -1."""
    stamps = _BASE + np.array([0, 10**9], dtype=np.int64)
    pos = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    query = _BASE + np.array([-1, 0, 10**9, 10**9 + 1])
    out = interpolate_poses(stamps, pos, _YAW_Q, query, max_gap_ns=0)
    assert out.ok.tolist() == [False, True, True, False]
    assert out.gap_ns.tolist() == [-1, 0, 0, -1]
    assert out.gap_ns.dtype == np.int64
    np.testing.assert_array_equal(out.T[1, :3, 3], pos[0])
    np.testing.assert_array_equal(out.T[2, :3, 3], pos[1])
    np.testing.assert_allclose(out.T[2, :3, :3], quat_to_rot(_YAW_Q[1]), atol=1e-15)
    np.testing.assert_array_equal(out.T[0], np.eye(4))
    np.testing.assert_array_equal(out.T[3], np.eye(4))


def test_interpolation_single_sample_and_no_samples() -> None:
    one = interpolate_poses([_BASE], [[1.0, 2.0, 3.0]], [[0.0, 0.0, 0.0, 1.0]],
                            [_BASE - 1, _BASE, _BASE + 1], max_gap_ns=10)
    assert one.ok.tolist() == [False, True, False]
    assert one.gap_ns.tolist() == [-1, 0, -1]
    np.testing.assert_array_equal(one.T[1, :3, 3], [1.0, 2.0, 3.0])
    none = interpolate_poses(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)),
                             [_BASE, _BASE + 5], max_gap_ns=10)
    assert none.T.shape == (2, 4, 4) and none.ok.tolist() == [False, False]
    assert none.gap_ns.tolist() == [-1, -1]
    assert none.ok.dtype == np.bool_ and none.gap_ns.dtype == np.int64
    np.testing.assert_array_equal(none.T, np.tile(np.eye(4), (2, 1, 1)))


def test_stamps_one_nanosecond_apart_are_increasing() -> None:
    stamps = _BASE + np.array([0, 1, 2], dtype=np.int64)
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    out = interpolate_poses(stamps, pos, quats, [_BASE + 1, _BASE + 2], max_gap_ns=1)
    assert out.ok.tolist() == [True, True]
    np.testing.assert_array_equal(out.T[:, 0, 3], [1.0, 2.0])


@pytest.mark.parametrize("stamps", [[5, 5], [0, 7, 7], [10, 3], [0, 10, 3]])
def test_equal_or_decreasing_stamps_are_refused(stamps: list[int]) -> None:
    t = _BASE + np.array(stamps, dtype=np.int64)
    pos = np.zeros((t.size, 3))
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (t.size, 1))
    with pytest.raises(DataError, match=r"^pose stamps must be strictly increasing$"):
        interpolate_poses(t, pos, quats, [_BASE], max_gap_ns=10)


def test_decreasing_unsigned_stamps_are_refused() -> None:
    """ROS stores stamps unsigned; a decrease must not wrap around into a large positive step."""
    t = np.array([_BASE + 10, _BASE], dtype=np.uint64)
    with pytest.raises(DataError, match="strictly increasing"):
        interpolate_poses(t, np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)),
                          [_BASE], max_gap_ns=100)


def test_unsigned_query_stamps_interpolate_to_the_nanosecond() -> None:
    """uint64 stamps near 1.7e18 ns: the fraction comes from exact integer differences (float64
    differences of such stamps would round to 256 ns)."""
    stamps = np.array([_BASE, _BASE + 1000], dtype=np.uint64)
    pos = np.array([[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0]])
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (2, 1))
    query = np.array([_BASE + 1, _BASE + 999], dtype=np.uint64)
    out = interpolate_poses(stamps, pos, quats, query, max_gap_ns=1000)
    assert out.ok.tolist() == [True, True]
    np.testing.assert_allclose(out.T[:, 0, 3], [1.0, 999.0], rtol=1e-12)


def test_float32_positions_are_interpolated_in_float64() -> None:
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 3.0, 0.1]], dtype=np.float32)
    out = interpolate_poses(_BASE + np.array([0, 3]), pos, _YAW_Q, [_BASE + 1], max_gap_ns=3)
    p0, p1 = pos.astype(np.float64)
    want = p0 + (1.0 / 3.0) * (p1 - p0)
    assert out.T.dtype == np.float64
    np.testing.assert_array_equal(out.T[0, :3, 3], want)


@pytest.mark.parametrize(("positions", "quats", "message"), [
    (np.zeros((2, 2)), np.zeros((2, 4)), r"positions must have shape \(2, 3\), got \(2, 2\)"),
    (np.zeros((3, 3)), np.zeros((2, 4)), r"positions must have shape \(2, 3\), got \(3, 3\)"),
    (np.zeros((2, 3)), np.zeros((2, 3)), r"quats must have shape \(2, 4\), got \(2, 3\)"),
    (np.array([[0.0, 0, 0], [np.nan, 0, 0]]), np.tile([0.0, 0, 0, 1], (2, 1)),
     r"positions has 1 non-finite value\(s\); first at index \(1, 0\)"),
])
def test_bad_pose_samples_are_refused_by_name(positions: np.ndarray, quats: np.ndarray,
                                              message: str) -> None:
    with pytest.raises(DataError, match=message):
        interpolate_poses(_BASE + np.array([0, 10]), positions, quats, [_BASE], max_gap_ns=10)


# --- transforms, quaternions, slerp, nearest stamps: batches, dtypes, edge cases --------------

def _yaw(a: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(a / 2), np.cos(a / 2)])


def test_compose_of_nothing_is_the_identity_and_integers_give_float64() -> None:
    np.testing.assert_array_equal(compose(), np.eye(4))
    shift = np.eye(4, dtype=np.int64)
    shift[0, 3] = 2
    out = compose(shift, shift)
    assert out.dtype == np.float64
    assert out[0, 3] == 4.0


def test_compose_and_invert_compute_float32_inputs_in_float64() -> None:
    T = make_T(quat_to_rot(_yaw(0.3)), [1.1, -2.3, 0.7]).astype(np.float32)
    T64 = T.astype(np.float64)
    np.testing.assert_array_equal(compose(T, T), T64 @ T64)
    np.testing.assert_array_equal(invert_T(T), invert_T(T64))
    assert compose(T, T).dtype == invert_T(T).dtype == np.float64


@settings(max_examples=20, deadline=None)
@given(T=st.lists(rigid_transforms(), min_size=2, max_size=4),
       q=st.lists(unit_quaternions(), min_size=2, max_size=4))
def test_batched_calls_equal_one_at_a_time(T: list[np.ndarray], q: list[np.ndarray]) -> None:
    """(..., 4, 4) and (..., 4) batches give per-element results (documented broadcasting)."""
    Ts, qs = np.stack(T), np.stack(q)
    inv = invert_T(Ts)
    for k in range(len(T)):
        np.testing.assert_allclose(inv[k], invert_T(T[k]), atol=1e-15)
    R = np.stack([t[:3, :3] for t in T])
    quats = rot_to_quat(R)
    assert quats.shape == (len(T), 4)
    for k in range(len(T)):
        np.testing.assert_allclose(quats[k], rot_to_quat(R[k]), atol=1e-15)
    unit = quat_normalize(qs * np.arange(1, len(q) + 1)[:, None])
    np.testing.assert_allclose(np.linalg.norm(unit, axis=-1), 1.0, rtol=1e-15)
    qb = np.roll(qs, 1, axis=0)
    frac = np.linspace(0.0, 1.0, len(q))
    mid = slerp(qs, qb, frac)
    assert mid.shape == (len(q), 4)
    for k in range(len(q)):
        np.testing.assert_allclose(mid[k], slerp(qs[k], qb[k], frac[k]), atol=1e-15)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rot_to_quat_of_half_turns(axis: int) -> None:
    """180 degrees about x, y or z: w = 0 and only one pivot of Shepperd's method is usable."""
    q = np.zeros(4)
    q[axis] = 1.0
    R = np.diag([-1.0, -1.0, -1.0])
    R[axis, axis] = 1.0
    got = rot_to_quat(R)
    assert np.isfinite(got).all()
    np.testing.assert_allclose(np.abs(got), q, atol=1e-15)
    np.testing.assert_allclose(quat_to_rot(got), R, atol=1e-15)


def test_quat_normalize_scales_refuses_zero_and_non_finite() -> None:
    np.testing.assert_array_equal(quat_normalize([0.0, 0.0, 0.0, 2.0]), [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(quat_to_rot([0.0, 0.0, 0.0, 3.0]), np.eye(3))
    got = quat_normalize(np.array([0.0, 0.6, 0.0, 0.8], dtype=np.float32))
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, np.array([0.0, 0.6, 0.0, 0.8], np.float32) / np.float64(
        np.linalg.norm(np.array([0.0, 0.6, 0.0, 0.8], np.float32).astype(np.float64))))
    np.testing.assert_array_equal(quat_normalize([0.0, 0.0, 0.0, 1e-12]), [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(DataError, match=r"^quaternion has zero norm; cannot normalize$"):
        quat_normalize([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0]])
    with pytest.raises(DataError, match=r"quaternion has 1 non-finite value\(s\); first at "
                                        r"index \(2,\)"):
        quat_normalize([0.0, 0.0, np.nan, 1.0])


def test_slerp_keeps_q1_when_the_dot_product_is_exactly_zero() -> None:
    """dot(q0, q1) = 0 is not the antipodal case (dot < 0): q1 is used as given, so halfway
    from the identity to a half turn about x is +90 degrees about x."""
    mid = slerp([0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], 0.5)
    np.testing.assert_allclose(mid, [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], atol=1e-15)


@pytest.mark.parametrize("s", [0.0, 0.25, 0.5, 1.0])
def test_slerp_of_nearly_equal_rotations_keeps_constant_speed(s: float) -> None:
    """Rotations 2e-6 rad apart (the normalized-lerp branch): the result is at s x the angle."""
    got = slerp(_yaw(0.0), _yaw(2e-6), s)
    np.testing.assert_allclose(got[2], np.sin(s * 1e-6), rtol=1e-9, atol=1e-22)
    np.testing.assert_allclose(np.linalg.norm(got), 1.0, rtol=1e-15)


def test_slerp_takes_a_float32_fraction_in_float64() -> None:
    s32 = np.float32(1.0 / 3.0)
    got = slerp(_yaw(0.0), _yaw(1.0), s32)
    np.testing.assert_allclose(got, slerp(_yaw(0.0), _yaw(1.0), float(s32)), rtol=0, atol=1e-16)
    np.testing.assert_allclose(got[2], np.sin(float(s32) / 2), rtol=1e-14)


def test_nearest_stamps_tie_picks_the_earlier_stamp() -> None:
    t = _BASE + np.array([0, 10, 20], dtype=np.int64)
    idx, dtau = nearest_stamps(_BASE + np.array([5, 15, 14, 16, -3, 25]), t)
    assert idx.tolist() == [0, 1, 1, 2, 0, 2]
    np.testing.assert_array_equal(dtau, np.array([-5, -5, -4, 4, 3, -5]) / 1e9)


def test_nearest_stamps_with_unsigned_stamps_is_exact_to_the_nanosecond() -> None:
    t = np.array([_BASE, _BASE + 10], dtype=np.uint64)
    idx, dtau = nearest_stamps(np.array([_BASE + 3, _BASE + 9], dtype=np.uint64), t)
    assert idx.tolist() == [0, 1]
    np.testing.assert_array_equal(dtau, [-3e-9, 1e-9])


def test_nearest_stamps_needs_a_stamp() -> None:
    with pytest.raises(DataError, match=r"^nearest_stamps needs at least one stamp$"):
        nearest_stamps([_BASE], np.zeros(0, np.int64))


def test_rot_to_quat_computes_float32_rotations_in_float64() -> None:
    R = quat_to_rot(_yaw(0.7) + np.array([0.1, -0.2, 0.0, 0.0]))
    R32 = R.astype(np.float32)
    got = rot_to_quat(R32)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, rot_to_quat(R32.astype(np.float64)))
