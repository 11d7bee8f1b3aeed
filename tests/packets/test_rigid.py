"""Rigid motions of point sets: into a camera from the world and back, pixels lifted at their
depth, rotation vectors."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from packets.poses import invert_T, make_T, quat_to_rot
from packets.projection import pinhole, transform_points
from packets.rigid import (
    apply_T,
    camera_from_world,
    lift_pixels,
    quat_pose_T,
    rotated,
    rotation_T,
    rotvec_matrix,
)

K = np.array([[30.0, 0.0, 20.5], [0.0, 30.0, 13.5], [0.0, 0.0, 1.0]])


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_T(Rotation.random(random_state=seed).as_matrix(), rng.normal(size=3) * 5)


def test_camera_from_world_inverts_the_pose() -> None:
    T = _pose(1)
    cam = np.random.default_rng(2).normal(size=(50, 3)) * 10
    world = transform_points(cam, T)
    np.testing.assert_allclose(camera_from_world(world, T), cam, atol=1e-12)
    np.testing.assert_allclose(camera_from_world(world, T), transform_points(world, invert_T(T)),
                               atol=1e-12)


def test_lifted_pixels_project_back_to_themselves_at_their_depth() -> None:
    T = _pose(3)
    rng = np.random.default_rng(4)
    uv = rng.uniform(0, 40, size=(6, 5, 2))  # any leading shape
    z = rng.uniform(0.5, 30, size=(6, 5))
    X = lift_pixels(uv, z, K, T)
    assert X.shape == (6, 5, 3)
    back, depth = pinhole(camera_from_world(X, T), K)
    np.testing.assert_allclose(back, uv, atol=1e-9)
    np.testing.assert_allclose(depth, z, rtol=1e-12)


def test_rotation_vectors_turn_points_and_poses_alike() -> None:
    r = np.array([0.1, -0.3, 0.2])
    R = rotvec_matrix(r)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(Rotation.from_matrix(R).as_rotvec() - r), 0,
                               atol=1e-12)
    E = rotation_T(r)
    np.testing.assert_array_equal(E[:3, 3], 0.0)
    np.testing.assert_array_equal(E[3], [0, 0, 0, 1])
    p = np.random.default_rng(5).normal(size=(10, 3))
    # a camera turned by r sees a point p of its old frame at R^T p
    np.testing.assert_allclose(rotated(p, r), transform_points(p, invert_T(E)), atol=1e-12)


def test_apply_T_is_the_frame_change_of_transform_points() -> None:
    T = _pose(6)
    for shape in [(1, 3), (7, 3), (400, 3), (5, 1, 3), (4, 6, 3)]:
        p = np.random.default_rng(7).normal(size=shape) * 10
        got = apply_T(p, T)
        assert got.shape == shape
        np.testing.assert_allclose(got, transform_points(p.reshape(-1, 3), T).reshape(shape),
                                   rtol=1e-15, atol=1e-13)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 40))
def test_quat_pose_T_is_the_edge_alignments_old_construction_bit_for_bit(seed: int, n: int) -> None:
    """`quat_pose_T` is the 4 x 4 the odometry track built inline (np.eye tiles, scipy's
    rotation, the positions) bit for bit, and `make_T(quat_to_rot)` to the last bits."""
    rng = np.random.default_rng(seed)
    quat, pos = rng.normal(size=(n, 4)), rng.normal(size=(n, 3)) * 50
    old = np.tile(np.eye(4), (n, 1, 1))
    old[:, :3, :3] = Rotation.from_quat(quat).as_matrix()
    old[:, :3, 3] = pos
    new = quat_pose_T(quat, pos)
    assert new.dtype == np.float64 and np.array_equal(new, old)
    np.testing.assert_allclose(new, make_T(quat_to_rot(quat), pos), rtol=0, atol=1e-13)
    np.testing.assert_array_equal(quat_pose_T(quat[0], pos[0]), old[0])
