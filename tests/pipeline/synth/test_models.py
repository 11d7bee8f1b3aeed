"""Properties of the camera model and the trajectory, for any coefficients and times."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from pipeline.synth.rig import FisheyeCamera
from pipeline.synth.trajectory import PathSpec, Trajectory
from tests.strategies import fisheye_D, walk_times_s


@settings(max_examples=25, deadline=None)
@given(D=fisheye_D, f_scale=st.floats(0.95, 1.3), cx_off=st.floats(-3.0, 3.0))
def test_pixel_rays_invert_opencv_fisheye(D: np.ndarray, f_scale: float, cx_off: float) -> None:
    w, h = 64, 48
    f = np.hypot(w / 2, h / 2) / np.deg2rad(80.0) * f_scale
    K = np.array([[f, 0.0, (w - 1) / 2 + cx_off], [0.0, 1.01 * f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    try:
        rays = FisheyeCamera("c", "c", w, h, K, D).pixel_rays().reshape(-1, 3).astype(np.float64)
    except ValueError as err:  # lenses beyond 90 deg are refused by design (tested below)
        assume("off-axis" not in str(err))
        raise
    uv, _ = cv2.fisheye.projectPoints(rays[:, None, :], np.zeros(3), np.zeros(3), K, D)
    v, u = np.mgrid[0:h, 0:w]
    np.testing.assert_allclose(uv.reshape(-1, 2), np.stack([u.ravel(), v.ravel()], 1), atol=2e-3)


def test_too_wide_a_lens_is_refused() -> None:
    K = np.array([[10.0, 0.0, 31.5], [0.0, 10.0, 23.5], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="off-axis"):
        FisheyeCamera("front", "hdr_front", 64, 48, K, np.zeros(4)).pixel_rays()


@settings(max_examples=50, deadline=None)
@given(t=walk_times_s, kind=st.sampled_from(["line", "loop"]))
def test_poses_are_rigid_and_walk_at_the_set_speed(t: float, kind: str) -> None:
    path = PathSpec(kind, 100.0, 9.0, 0.12, 3.0 if kind == "loop" else 9.0)
    traj = Trajectory(path, 0.8, phase=0.4)
    T = traj.poses([t, t + 0.01])
    R = T[0, :3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(R) - 1) < 1e-12 and T[0, 3].tolist() == [0, 0, 0, 1]
    assert 0.5 < T[0, 2, 3] < 0.6  # base height with the gait bob
    speed = np.linalg.norm(T[1, :2, 3] - T[0, :2, 3]) / 0.01
    assert 0.6 < speed < 1.1
    roll_pitch = np.arcsin(np.clip(-R[2, 0], -1, 1)), np.arctan2(R[2, 1], R[2, 2])
    assert max(abs(a) for a in roll_pitch) < np.deg2rad(4.0)
