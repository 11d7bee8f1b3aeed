"""Geometry, calibration and timing agree: a sweep projected into a fisheye image through the
odometry chain lands at the ground-truth depth; the fisheye ray model inverts OpenCV's."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import zarr

from packets.poses import compose, invert_T
from pipeline.synth.api import SynthResult, synthesize
from pipeline.synth.groundtruth import pose_at, read_poses
from pipeline.synth.rig import FisheyeCamera
from schemas.config import SynthConfig
from tests.pipeline.synth.helpers import calibration, cloud_points, read_topic, stamp_ns, table

SIGMA = 0.02  # SynthConfig.lidar_range_noise_m default


def test_pixel_rays_reproject_to_pixel_centres() -> None:
    K = np.array([[60.0, 0, 63.2], [0, 60.3, 47.9], [0, 0, 1]])
    cam = FisheyeCamera("front", "hdr_front", 128, 96, K, np.array([0.03, -0.01, 0.002, -3e-4]))
    rays = cam.pixel_rays().reshape(-1, 3).astype(np.float64)
    uv, _ = cv2.fisheye.projectPoints(rays[:, None, :], np.zeros(3), np.zeros(3), K, cam.D)
    v, u = np.mgrid[0:96, 0:128]
    np.testing.assert_allclose(uv.reshape(-1, 2), np.stack([u.ravel(), v.ravel()], 1), atol=1e-3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-6)


def _bilinear(dmap: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth at sub-pixel (u, v) (N, 2) and whether all four neighbours are hits and inside."""
    h, w = dmap.shape
    u0, v0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    ok = (u0 >= 0) & (u0 < w - 1) & (v0 >= 0) & (v0 < h - 1)
    u0, v0 = np.where(ok, u0, 0), np.where(ok, v0, 0)
    a, b = uv[:, 0] - u0, uv[:, 1] - v0
    q = [dmap[v0, u0], dmap[v0, u0 + 1], dmap[v0 + 1, u0], dmap[v0 + 1, u0 + 1]]
    ok &= np.all(np.stack(q) > 0, axis=0)
    d = (1 - a) * (1 - b) * q[0] + a * (1 - b) * q[1] + (1 - a) * b * q[2] + a * b * q[3]
    return d, ok


def _depth_errors(res: SynthResult, cam: str, wrong_time: bool = False) -> np.ndarray:
    """|projected z - true depth| over all sweep points landing on hit pixels, all images.

    `wrong_time` (a negative control) chains the sweep 3 places after the nearest one with the
    pose of the nearest sweep's stamp, i.e. ignores 0.3 s of motion."""
    gt_dir = res.groundtruth_dir
    calib, poses = calibration(gt_dir), read_poses(gt_dir)
    K, D = np.array(calib["cameras"][cam]["K"]), np.array(calib["cameras"][cam]["D"])
    T_base_cam = np.array(calib["T_base_sensor"][cam])
    T_base_lidar = np.array(calib["T_base_sensor"]["lidar"])
    depth = zarr.open_array(str(gt_dir / "depth" / f"{cam}.zarr"))
    sweeps = {stamp_ns(m.header): m for _, m in
              read_topic(res.bags["hesai_undist"], "/boxi/hesai/points_undistorted")}  # fmt: skip
    s_st = np.array(sorted(sweeps))
    imgs = table(gt_dir, "images")
    errs = []
    for c, tau, k in zip(imgs["camera"], imgs["stamp_ns"], imgs["depth_index"], strict=True):
        if c != cam:
            continue
        j = int(np.abs(s_st - tau).argmin())
        skip = 3 if wrong_time else 0
        if abs(s_st[j] - tau) > 0.1e9 or j + skip >= s_st.size:
            continue
        tau_p, tau_chain = int(s_st[j + skip]), int(s_st[j])
        T_cam_lidar = compose(
            invert_T(T_base_cam),
            invert_T(pose_at(poses, tau)),
            pose_at(poses, tau_chain),
            T_base_lidar,
        )
        pts = cloud_points(sweeps[tau_p])
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], 1).astype(np.float64)
        pc = xyz @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
        front = pc[:, 2] > 0.5
        uv, _ = cv2.fisheye.projectPoints(pc[front][:, None, :], np.zeros(3), np.zeros(3), K, D)
        d_true, ok = _bilinear(depth[k], uv.reshape(-1, 2))
        errs.append(np.abs(pc[front][ok, 2] - d_true[ok]))
    return np.concatenate(errs)


def test_sweep_projects_onto_true_depth(clean: SynthResult) -> None:
    for cam in ("front", "left", "right"):
        err = _depth_errors(clean, cam)
        assert err.size > 300, cam
        assert np.median(err) < SIGMA, (cam, float(np.median(err)))


def test_wrong_sweep_time_is_detected(clean: SynthResult) -> None:
    """Negative control: the chain with a sweep 0.3 s off (24 cm of motion) does not agree."""
    err = _depth_errors(clean, "front", wrong_time=True)
    assert np.median(err) > 2 * SIGMA


def test_noiseless_sweep_matches_depth_to_the_millimetre(tmp_path: Path) -> None:
    cfg = SynthConfig(seconds=1.0, image_width=128, image_height=96, points_per_sweep=2048,
                      cameras=["front"], lidar_range_noise_m=0.0)  # fmt: skip
    res = synthesize(tmp_path, cfg, "corridor")
    err = _depth_errors(res, "front")
    assert err.size > 300 and np.median(err) < 2e-3


def test_camera_frames_are_optical_and_mounted_like_grandtour(clean: SynthResult) -> None:
    calib = calibration(clean.groundtruth_dir)
    looks = {"front": [1, 0, 0], "left": [0, 1, 0], "right": [0, -1, 0]}
    for cam, axis in looks.items():
        T = np.array(calib["T_base_sensor"][cam])
        z_opt, y_opt = T[:3, 2], T[:3, 1]
        assert np.dot(z_opt, axis) > 0.95  # optical z looks out of the named side
        assert z_opt[2] < -0.1  # tilted down a little
        assert y_opt[2] < -0.9  # optical y points down
    edges = {(e["parent"], e["child"]) for e in calib["edges"]}
    assert ("box_base", "hesai_lidar") in edges and ("hdr_base", "hdr_front") in edges
    T_lidar = np.array(calib["T_base_sensor"]["lidar"])
    assert T_lidar[2, 2] > 0.99 and T_lidar[2, 3] > 0.3  # z up, on top of the box
