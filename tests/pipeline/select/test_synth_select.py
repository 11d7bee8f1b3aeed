"""Select on synthetic recordings: nearest sweeps and Δτ exact, T_cam_lidar vs ground truth,
the selected sweep projected into the rectified output agrees with the ground-truth depth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr
from scipy.spatial.transform import Rotation, Slerp

from packets.projection import project_points
from pipeline.ingest.calib.camera import RawCamera, build_rectifier, rectify_nearest
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.sweep_reader import load_sweep
from pipeline.select import SelectResult, select_views
from pipeline.synth.groundtruth import pose_at, read_poses
from schemas.config import SelectConfig
from schemas.recording_index import (
    CALIBRATION,
    ODOMETRY,
    SELECTION,
    SWEEPS,
    read_index_table,
    table_path,
)
from tests.pipeline.synthkit import INGEST, gt_json, gt_T_base, gt_table, recording


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, SelectResult]:
    mission = recording(tmp_path_factory, "clean")
    res = ingest_recording(mission, tmp_path_factory.mktemp("select_clean"), INGEST)
    return mission, res.index_dir, select_views(res.index_dir, SelectConfig(), INGEST)


def _selection(idx: Path) -> list[dict[str, Any]]:
    return read_index_table(table_path(idx, "selection"), SELECTION).to_pylist()


def test_nearest_sweep_and_dtau_match_ground_truth(clean: tuple) -> None:
    mission, idx, result = clean
    sweeps = np.array([r["stamp_ns"] for r in gt_table(mission, "sweeps")], dtype=np.int64)
    rows = _selection(idx)
    assert len(rows) == result.views == len(gt_table(mission, "images"))
    for r in rows:
        d = [abs(int(s) - r["stamp_ns"]) for s in sweeps]
        gt = int(np.argmin(d))
        assert r["sweep"] == gt and r["sweep_stamp_ns"] == sweeps[gt]
        assert r["dtau_s"] == (int(sweeps[gt]) - r["stamp_ns"]) / 1e9
        ok = abs(r["dtau_s"]) <= 0.1
        assert (r["status"], r["reason"]) == (("ok", "") if ok else ("rejected", "dtau_exceeded"))
    assert result.rejected.get("dtau_exceeded", 0) >= 3  # cameras start 0.3 s before the LiDAR
    assert result.sweeps_selected + result.sweeps_unselected == len(sweeps)


def _gt_interp(stamps: np.ndarray, T: np.ndarray, t: int) -> np.ndarray:
    """Independent reference: np.interp positions, scipy Slerp rotations, from int64 stamps."""
    rel = (stamps - stamps[0]).astype(np.float64)
    x = float(t - stamps[0])
    out = np.eye(4)
    out[:3, 3] = [np.interp(x, rel, T[:, i, 3]) for i in range(3)]
    out[:3, :3] = Slerp(rel, Rotation.from_matrix(T[:, :3, :3]))([x]).as_matrix()[0]
    return out


def test_T_cam_lidar_matches_ground_truth_chain(clean: tuple) -> None:
    mission, idx, _ = clean
    poses = read_poses(mission / "groundtruth")
    odo_t = read_index_table(table_path(idx, "odometry"), ODOMETRY).column("stamp_ns").to_numpy()
    odo_T = np.stack([pose_at(poses, int(t)) for t in odo_t])  # ground truth at odometry stamps
    T_base_lidar = gt_T_base(mission, "lidar")
    worst_true = 0.0
    for r in (r for r in _selection(idx) if r["status"] == "ok"):
        T_base_cam = gt_T_base(mission, r["camera"])
        T_img = _gt_interp(odo_t, odo_T, r["stamp_ns"])
        T_swp = _gt_interp(odo_t, odo_T, r["sweep_stamp_ns"])
        gt = np.linalg.inv(T_base_cam) @ np.linalg.inv(T_img) @ T_swp @ T_base_lidar
        np.testing.assert_allclose(np.reshape(r["T_cam_lidar"], (4, 4)), gt, atol=1e-6)
        np.testing.assert_allclose(np.reshape(r["T_world_cam"], (4, 4)), T_img @ T_base_cam,
                                   atol=1e-6)  # fmt: skip
        true = (np.linalg.inv(T_base_cam) @ np.linalg.inv(pose_at(poses, r["stamp_ns"]))
                @ pose_at(poses, r["sweep_stamp_ns"]) @ T_base_lidar)  # fmt: skip
        worst_true = max(worst_true, float(np.abs(true - gt)[:3, 3].max()))
    assert worst_true < 0.01  # 20 Hz odometry interpolation vs the true trajectory: < 1 cm


def _depth_errors(mission: Path, idx: Path, rectified: bool) -> np.ndarray:
    """Signed relative depth error of projected selected sweeps vs ground-truth depth maps.

    rectified: project with K_out into the output view and rectify the ground-truth depth with a
    nearest-neighbour remap; else project with the raw fisheye model into the raw depth map
    (the error floor of the data itself: range noise and pixel quantization).
    """
    calib = {r["sensor"]: r for r in read_index_table(table_path(idx, "calibration"),
                                                      CALIBRATION).to_pylist()}  # fmt: skip
    sweeps = read_index_table(table_path(idx, "sweeps"), SWEEPS).to_pylist()
    gt_img = {(r["camera"], r["stamp_ns"]): r for r in gt_table(mission, "images")}
    hw = (INGEST.out_height, INGEST.out_width)
    rows = [r for r in _selection(idx) if r["status"] == "ok"]
    errors = []
    for r in rows[:: max(1, len(rows) // 6)]:
        c = calib[r["camera"]]
        K, D = np.reshape(c["K"], (3, 3)), np.asarray(c["D"])
        cam = RawCamera(r["camera"], c["frame_id"], c["width"], c["height"], "equidistant", K, D)
        rect = build_rectifier(cam, hw, INGEST.rectify_balance)
        np.testing.assert_allclose(rect.K_out.ravel(), r["K_out"], atol=1e-12)
        store = str(mission / "groundtruth" / "depth" / f"{r['camera']}.zarr")
        row = gt_img[(r["camera"], r["stamp_ns"])]["depth_index"]
        depth_raw = np.asarray(zarr.open_array(store, mode="r")[row], np.float32)
        sweep = load_sweep(mission, sweeps[r["sweep"]])
        T = np.reshape(r["T_cam_lidar"], (4, 4))
        if rectified:
            proj = project_points(sweep.xyz, rect.K_out, T, hw)
            depth_gt = rectify_nearest(depth_raw, rect)
        else:
            proj = project_points(sweep.xyz, K, T, (c["height"], c["width"]), "equidistant", D)
            depth_gt = depth_raw
        uv = np.rint(proj.uv[proj.valid]).astype(int)
        d_gt = depth_gt[uv[:, 1], uv[:, 0]]
        hit = d_gt > 0
        errors.append((proj.depth[proj.valid][hit] - d_gt[hit]) / d_gt[hit])
    return np.concatenate(errors)


def test_projected_sweep_agrees_with_ground_truth_depth(clean: tuple) -> None:
    mission, idx, _ = clean
    err = _depth_errors(mission, idx, rectified=True)
    floor = _depth_errors(mission, idx, rectified=False)
    assert err.size > 500
    assert abs(np.median(err)) < 0.002  # no bias: points land on the surfaces the camera sees
    assert np.median(np.abs(err)) < 0.015
    assert np.median(np.abs(err)) < 1.3 * np.median(np.abs(floor))  # rectification adds ~nothing
    assert np.mean(np.abs(err) < 0.05) > 0.9  # the rest: occlusion and depth edges


def test_lidar_gap_views_rejected_and_sweeps_counted(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    mission = recording(tmp_path_factory, "faulty")
    res = ingest_recording(mission, tmp_path_factory.mktemp("select_faulty"), INGEST)
    out = select_views(res.index_dir, SelectConfig(), INGEST)
    rows = _selection(res.index_dir)
    assert {r["camera"] for r in rows} == {"front", "left"}  # right has no camera_info
    gap = next(f for f in gt_json(mission, "faults")["faults"] if f["kind"] == "lidar_gap")
    mid_gap = [r for r in rows if gap["start_ns"] + 2e8 < r["stamp_ns"] < gap["end_ns"] - 2e8]
    assert mid_gap and all(r["reason"] == "dtau_exceeded" for r in mid_gap)
    assert out.sweeps_unselected == out.sweeps_total - len(
        {r["sweep"] for r in rows if r["status"] == "ok"})
