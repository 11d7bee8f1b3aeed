"""Reprojection consistency: an analytic textured wall seen by a moving, turning camera whose
images are taken off the recorded track (clock offset) and off its recorded mounting
(extrinsic rotation); the sweep recovers both."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from packets.reprojection_consistency import (
    CubicTrack,
    Pair,
    Track,
    lift_cells,
    objective,
    pair_error,
    sweep,
)
from packets.rigid import rotation_T as rotation

HW = (72, 96)
K = np.array([[70.0, 0.0, 47.5], [0.0, 70.0, 35.5], [0.0, 0.0, 1.0]])
WALL_Z = 14.0
NS = 1_000_000_000


def pose(t: float) -> np.ndarray:
    """T_world_cam of the recorded track at t s: forward, weaving and turning."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.3 * np.sin(1.3 * t), 0.0]).as_matrix()
    T[:3, 3] = [1.0 * np.sin(1.7 * t), 0.1 * t, 2.0 * t]
    return T


def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return (128 + 45 * np.sin(2 * np.pi * x / 3.4) + 35 * np.sin(2 * np.pi * y / 2.2 + 0.4 * x)
            + 20 * np.cos(2 * np.pi * (x + y) / 4.6))


def wall_points(T: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Where the rays of pixels uv (N, 2) of camera T hit the wall z = WALL_Z (N, 3)."""
    pix = np.concatenate([uv, np.ones_like(uv[:, :1])], 1) @ np.linalg.inv(K).T
    d = pix @ T[:3, :3].T
    lam = (WALL_Z - T[2, 3]) / d[:, 2]
    out: np.ndarray = T[:3, 3] + lam[:, None] * d
    return out


def render(T: np.ndarray) -> np.ndarray:
    v, u = np.mgrid[0:HW[0], 0:HW[1]].astype(np.float64)
    X = wall_points(T, np.stack([u.ravel(), v.ravel()], 1))
    return texture(X[:, 0], X[:, 1]).reshape(*HW, 1)


def scene(offset_s: float, rot_rad: tuple[float, float, float]) -> tuple[list[Pair], Track]:
    stamps = np.arange(0, 41) * 0.05  # recorded track: 0 .. 2 s at 20 Hz
    track = Track((stamps * NS).round().astype(np.int64), np.stack([pose(t) for t in stamps]))
    E = rotation(rot_rad)
    views = np.arange(0.3, 1.75, 0.1)  # image stamps (s)
    images = [render(pose(t - offset_s) @ E) for t in views]
    gv, gu = np.mgrid[2:HW[0]:5, 2:HW[1]:5].astype(np.float64)
    grid = np.stack([gu.ravel(), gv.ravel()], 1)
    pairs = [Pair(images[i], images[j], K, K, round(views[i] * NS), round(views[j] * NS),
                  wall_points(pose(views[i]), grid))  # the LiDAR's points: the true wall
             for i in range(len(views)) for j in (i + 4, i + 8) if j < len(views)]
    return pairs, track


def test_consistent_recording_has_zero_error_at_the_recorded_calibration() -> None:
    pairs, track = scene(0.0, (0.0, 0.0, 0.0))
    at_truth = objective(pairs, track, 0.0, (0.0, 0.0, 0.0))  # bilinear reads: not exactly 0
    # the clock offset and the turn axis (yaw) are seen strongly on this track; a pitch error
    # moves the points of both views alike (a flat wall, little vertical motion) and is seen
    # weakly (the sweep still recovers it within 0.2 deg below)
    assert objective(pairs, track, 0.02, (0.0, 0.0, 0.0)) > 3 * at_truth
    assert objective(pairs, track, 0.0, (0.0, 0.005, 0.0)) > at_truth


@pytest.mark.parametrize(("offset_s", "rot_deg"), [(0.03, (0.0, 0.5, 0.0)),
                                                   (-0.02, (0.4, 0.0, -0.3))])
def test_sweep_recovers_an_injected_clock_offset_and_extrinsic_rotation(
        offset_s: float, rot_deg: tuple[float, float, float]) -> None:
    pairs, track = scene(offset_s, tuple(np.radians(rot_deg)))  # type: ignore[arg-type]
    est = sweep(pairs, track, np.round(np.arange(-0.06, 0.0601, 0.005), 6),
                np.radians(np.arange(-1.0, 1.01, 0.1)))
    assert abs(est.offset_s - offset_s) < 0.005
    err_deg = np.degrees((Rotation.from_rotvec(est.rotation_rad).inv()
                          * Rotation.from_rotvec(np.radians(rot_deg))).magnitude())
    assert err_deg < 0.2, (est, err_deg)
    assert est.error_min < 0.1 * est.error_nominal


def test_pair_without_common_points_reports_none() -> None:
    img = np.zeros((*HW, 1))
    p = Pair(img, img, K, K, 0, 1, np.array([[0.0, 0.0, -5.0]]))  # behind the camera
    e, n = pair_error(p, np.eye(4), np.eye(4))
    assert n == 0 and np.isnan(e)


def test_lift_cells_places_points_on_the_cells_rays_at_their_depth() -> None:
    depth = np.zeros((2, 3))
    depth[1, 2] = 5.0
    X = lift_cells(depth, K, np.eye(4), (28, 42), per_side=2)
    assert X.shape == (4, 3) and np.allclose(X[:, 2], 5.0)
    uv = X[:, :2] / X[:, 2:] * 70.0 + [47.5, 35.5]
    assert ((uv[:, 0] > 27.5) & (uv[:, 0] < 41.5) & (uv[:, 1] > 13.5)).all()


def test_track_interpolates_between_samples_and_refuses_outside() -> None:
    T0, T1 = np.eye(4), rotation((0.0, 0.2, 0.0))
    T1[:3, 3] = [2.0, 0.0, 0.0]
    tr = Track([0, 10], np.stack([T0, T1]))
    mid = tr.at(5)
    assert mid is not None and np.allclose(mid[:3, 3], [1.0, 0, 0])
    assert np.allclose(mid[:3, :3], rotation((0.0, 0.1, 0.0))[:3, :3])
    assert tr.at(-1) is None and tr.at(11) is None
    with pytest.raises(ValueError, match="increasing"):
        Track([0, 0], np.stack([T0, T1]))


def turning(t: np.ndarray) -> np.ndarray:
    """T (N, 4, 4) of a body yawing at 1.5 sin(pi t) rad/s (a 2 s period), pitching by
    0.05 sin(3 t) rad and moving along a curve, at times t (N,) s."""
    yaw = -1.5 / np.pi * np.cos(np.pi * t)
    T = np.tile(np.eye(4), (t.size, 1, 1))
    T[:, :3, :3] = Rotation.from_euler("zy", np.stack([yaw, 0.05 * np.sin(3 * t)], 1)).as_matrix()
    T[:, :3, 3] = np.stack([2.0 * t, 0.3 * np.sin(2 * t), 0.0 * t], 1)
    return T


def angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    """Angle (deg) between the rotations of two poses (4, 4)."""
    return float(np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude()))


def test_cubic_track_reads_a_turning_body_where_slerp_errs() -> None:
    stamps = np.arange(0, 61) * 0.05  # 20 Hz over 3 s
    T = turning(stamps)
    ns = (stamps * NS).round().astype(np.int64)
    lin, cub = Track(ns, T), CubicTrack(ns, T)
    q = np.linspace(0.3, 2.7, 97)  # off-sample queries, away from the ends
    truth = turning(q)
    err_lin = max(angle_deg(lin.at(t * NS), truth[k]) for k, t in enumerate(q))  # type: ignore[arg-type]
    err_cub = max(angle_deg(cub.at(t * NS), truth[k]) for k, t in enumerate(q))  # type: ignore[arg-type]
    pos_cub = max(float(np.linalg.norm(cub.at(t * NS)[:3, 3] - truth[k][:3, 3]))  # type: ignore[index]
                  for k, t in enumerate(q))
    # slerp: up to a h^2 / 8 = 1.5 pi 0.05^2 / 8 rad = 0.084 deg (measured 0.0841); the cubic
    # through 6 samples a side 5.8e-5 deg, 1.1e-7 m
    assert 0.05 < err_lin < 0.09, err_lin
    assert err_cub < 5e-4 and pos_cub < 1e-5, (err_cub, pos_cub)


def test_cubic_track_is_exact_at_samples_linear_when_short_and_refuses_outside() -> None:
    stamps = np.arange(0, 11) * 0.05
    T = turning(stamps)
    ns = (stamps * NS).round().astype(np.int64)
    cub = CubicTrack(ns, T)
    assert all(np.array_equal(cub.at(int(t)), T[k]) for k, t in enumerate(ns))  # type: ignore[arg-type]
    assert cub.at(int(ns[0]) - 1) is None and cub.at(int(ns[-1]) + 1) is None
    short = CubicTrack(ns[:3], T[:3])  # fewer than 4 samples: the linear track
    assert np.array_equal(short.at(0.07 * NS), Track(ns[:3], T[:3]).at(0.07 * NS))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="half_window"):
        CubicTrack(ns, T, half_window=1)
