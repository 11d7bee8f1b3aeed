"""Ingest on tiny missions written in the test: index contents and every bad-input case."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.calib.tf_tree import MissingTransformError
from pipeline.ingest.core.stream import CameraImage
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.sweep_reader import load_sweep
from schemas.config import IngestConfig
from schemas.recording_index import (
    CALIBRATION,
    DAMAGE,
    IMAGES,
    REJECTS,
    SWEEPS,
    read_index_table,
    table_path,
)
from tests.pipeline.ingest.bagkit import (
    Mission,
    camera_stamps,
    gt_T_base,
    lidar_stamps,
    sweep_points,
    write_mission,
)

CFG = IngestConfig(cameras=["front"], out_height=28, out_width=42)


def _rejects(idx: Path) -> list[dict]:
    return read_index_table(table_path(idx, "rejects"), REJECTS).to_pylist()


def test_clean_mission_index_and_images(tmp_path: Path) -> None:
    m = Mission()
    mission = write_mission(tmp_path, m)
    got: list[CameraImage] = []
    res = ingest_recording(mission, tmp_path / "out", CFG, image_sink=got.append)
    assert res.images == {"front": 10} and res.sweeps == 10 and res.rejects == {}
    images = read_index_table(table_path(res.index_dir, "images"), IMAGES).to_pylist()
    assert [r["stamp_ns"] for r in images] == camera_stamps(m)
    assert [r["frame"] for r in images] == list(range(10))
    assert images[0]["file"] == "m0_hdr_front.bag" and images[0]["ordinal"] == 0
    assert [g.frame for g in got] == list(range(10))
    assert [g.stamp_ns for g in got] == camera_stamps(m)
    assert got[0].image.shape == (28, 42, 3) and got[0].image.dtype == np.uint8
    sweeps = read_index_table(table_path(res.index_dir, "sweeps"), SWEEPS).to_pylist()
    assert [r["stamp_ns"] for r in sweeps] == lidar_stamps(m)
    assert sweeps[0]["n_valid"] == m.points
    assert sweeps[0]["t_last_ns"] - sweeps[0]["t_first_ns"] == pytest.approx(90_000_000, abs=1e3)
    calib = {r["sensor"]: r for r in read_index_table(
        table_path(res.index_dir, "calibration"), CALIBRATION).to_pylist()}  # fmt: skip
    for sensor, frame in [("front", "hdr_front"), ("lidar", "hesai_lidar")]:
        T = np.asarray(calib[sensor]["T_base_sensor"]).reshape(4, 4)
        np.testing.assert_allclose(T, gt_T_base(frame), atol=1e-12)
    np.testing.assert_allclose(np.asarray(calib["front"]["K_out"]).reshape(3, 3), got[0].K_out)


def test_load_sweep_returns_the_indexed_points(tmp_path: Path) -> None:
    m = Mission(nan_points=3)
    mission = write_mission(tmp_path, m)
    res = ingest_recording(mission, tmp_path / "out", CFG)
    rows = read_index_table(table_path(res.index_dir, "sweeps"), SWEEPS).to_pylist()
    sweep = load_sweep(mission, rows[4])
    pts = sweep_points(4, m.points, nan_points=3)[6:]
    np.testing.assert_array_equal(sweep.xyz[:, 2], pts["z"])
    assert sweep.counts.nonfinite == 3 and sweep.counts.zero == 3
    assert rows[4]["n_valid"] == sweep.counts.valid == m.points - 6


def test_faults_are_rejected_and_the_rest_kept(tmp_path: Path) -> None:
    m = Mission(corrupt_jpeg_at={3}, duplicate_image_at={5}, swap_images_at={7},
                empty_sweep_at={4})  # fmt: skip
    mission = write_mission(tmp_path, m)
    res = ingest_recording(mission, tmp_path / "out", CFG)
    rej = _rejects(res.index_dir)
    by = {r["reason"]: r for r in rej}
    assert sorted(r["reason"] for r in rej) == [
        "corrupt_jpeg", "duplicate_stamp", "empty_sweep", "out_of_order_stamp",
        "out_of_order_stamp"]  # fmt: skip
    cam = camera_stamps(m)
    assert by["corrupt_jpeg"]["stamp_ns"] == cam[3]
    assert by["corrupt_jpeg"]["file"] == "m0_hdr_front.bag"
    assert by["corrupt_jpeg"]["topic"] == "/boxi/hdr/front/image_raw/compressed"
    assert by["duplicate_stamp"]["stamp_ns"] == cam[5]
    # images 7 and 8 exchanged header stamps: neither stamp can be trusted, both refused
    ooo = [r["stamp_ns"] for r in rej if r["reason"] == "out_of_order_stamp"]
    assert ooo == [cam[8], cam[7]]
    assert by["empty_sweep"]["stamp_ns"] == lidar_stamps(m)[4]
    images = pq.read_table(table_path(res.index_dir, "images")).column("stamp_ns").to_pylist()
    assert images == [s for i, s in enumerate(cam) if i not in (3, 7, 8)]
    assert res.sweeps == 9


def test_corrupt_poses_are_rejected_naming_file_topic_and_stamp(tmp_path: Path) -> None:
    m = Mission(bad_pose_at={4: (1e308, 0.0, 0.0), 9: (float("nan"), 0.0, 0.0)})
    res = ingest_recording(write_mission(tmp_path, m), tmp_path / "out", CFG)
    bad = [r for r in _rejects(res.index_dir) if r["topic"] == "/anymal/state_estimator/odometry"]
    assert [r["reason"] for r in bad] == ["bad_pose"] * 2
    assert "a corrupt pose" in bad[0]["detail"] and "non-finite" in bad[1]["detail"]
    assert all(r["file"] == "m0_anymal_state.bag" for r in bad)
    poses = pq.read_table(table_path(res.index_dir, "odometry")).column("position").to_pylist()
    assert max(abs(v) for p in poses for v in p) < 100 and len(poses) == res.odometry


def test_truncated_bag_is_read_up_to_the_damage(tmp_path: Path) -> None:
    full = write_mission(tmp_path / "a", Mission(points=2000))
    size = (full / "m0_hesai_undist.bag").stat().st_size
    mission = write_mission(
        tmp_path / "b", Mission(points=2000, truncate_lidar_bytes=size * 6 // 10)
    )
    res = ingest_recording(mission, tmp_path / "out", CFG)
    rej = [r for r in _rejects(res.index_dir) if r["reason"] == "truncated_bag"]
    assert len(rej) == 1 and rej[0]["file"] == "m0_hesai_undist.bag"
    assert 0 < res.sweeps < 10
    kept = pq.read_table(table_path(res.index_dir, "sweeps")).column("stamp_ns").to_pylist()
    assert kept == lidar_stamps(Mission())[: res.sweeps]
    assert rej[0]["stamp_ns"] == kept[-1]
    assert res.images == {"front": 10}
    rows = read_index_table(table_path(res.index_dir, "sweeps"), SWEEPS).to_pylist()
    assert load_sweep(mission, rows[-1]).counts.valid == 2000


def test_garbled_chunk_keeps_the_other_bags_and_names_the_damage(tmp_path: Path) -> None:
    mission = write_mission(tmp_path / "m", Mission(points=2000))
    bag = mission / "m0_hesai_undist.bag"
    data = bytearray(bag.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 4096] = np.random.default_rng(0).integers(0, 256, 4096, np.uint8).tobytes()
    bag.write_bytes(bytes(data))
    res = ingest_recording(mission, tmp_path / "out", CFG)
    rej = [r for r in _rejects(res.index_dir) if r["reason"] == "damaged_region"]
    assert rej and {r["file"] for r in rej} == {"m0_hesai_undist.bag"}
    assert all("unreadable" in r["detail"] and "could have held" in r["detail"] for r in rej)
    damage = read_index_table(table_path(res.index_dir, "damage"), DAMAGE).to_pylist()
    assert len(damage) == len(rej) and all(d["byte_start"] < mid + 4096 for d in damage)
    # every sweep is either kept or counted in a damaged region (the chunk index knows which)
    lost = sum(d["messages"] for d in damage)
    assert lost > 0 and res.sweeps + lost == 10 and res.images == {"front": 10}


def test_topic_typo_fails_before_any_work_and_suggests_the_real_topic(tmp_path: Path) -> None:
    mission = write_mission(tmp_path / "m", Mission())
    typo = CFG.model_copy(update={"topics": CFG.topics.model_copy(
        update={"lidar": "/boxi/hesai/points_undistorted_typo"})})
    with pytest.raises(ValueError, match=r"no bag holds the LiDAR topic "
                       r"/boxi/hesai/points_undistorted_typo \(bags: m0_.*\); "
                       r"did you mean /boxi/hesai/points_undistorted\?"):
        ingest_recording(mission, tmp_path / "out", typo)
    assert not (tmp_path / "out" / "index" / "m0" / "images.parquet").exists()


def test_bag_level_damage_is_told_not_only_tabled(tmp_path: Path) -> None:
    full = write_mission(tmp_path / "a", Mission(points=2000))
    size = (full / "m0_hesai_undist.bag").stat().st_size
    mission = write_mission(tmp_path / "b", Mission(points=2000, truncate_lidar_bytes=size // 2))
    res = ingest_recording(mission, tmp_path / "out", CFG)
    told = [w for w in res.warnings if w.startswith("m0_hesai_undist.bag: ")]
    assert len(told) == 1 and "truncated_bag" in told[0] and "could have held" in told[0]


def test_missing_or_empty_calibration_bag_is_named(tmp_path: Path) -> None:
    mission = write_mission(tmp_path / "m", Mission())
    (mission / "m0_tf_minimal.bag").unlink()
    with pytest.raises(ValueError, match=r"no bag holds the calibration topic /tf_static"):
        ingest_recording(mission, tmp_path / "out", CFG)
    (mission / "m0_tf_minimal.bag").write_bytes(b"")
    with pytest.raises(ValueError, match=r"no bag holds the calibration topic /tf_static .*"
                                         r"damaged: m0_tf_minimal\.bag \(.*empty file"):
        ingest_recording(mission, tmp_path / "out", CFG)


def test_a_file_that_is_not_a_bag_is_named_and_the_rest_kept(tmp_path: Path) -> None:
    mission = write_mission(tmp_path / "m", Mission())
    (mission / "m0_hdr_left.bag").write_text("not a bag at all\n")
    res = ingest_recording(mission, tmp_path / "out", CFG)
    rej = [r for r in _rejects(res.index_dir) if r["file"] == "m0_hdr_left.bag"]
    assert [r["reason"] for r in rej] == ["unreadable_bag"] and rej[0]["topic"] == ""
    assert "no message could be read" in rej[0]["detail"]
    assert any(w.startswith("m0_hdr_left.bag: unreadable_bag: ") for w in res.warnings)
    assert res.images == {"front": 10} and res.sweeps == 10


def test_missing_camera_info_skips_that_camera_only(tmp_path: Path) -> None:
    m = Mission(cameras=("front", "left"), no_camera_info={"left"})
    mission = write_mission(tmp_path, m)
    cfg = IngestConfig(cameras=["front", "left"], out_height=28, out_width=42)
    res = ingest_recording(mission, tmp_path / "out", cfg)
    rej = _rejects(res.index_dir)
    # bagkit publishes no TF edge for hdr_left: recorded, not fatal, as the camera is skipped
    assert [r["reason"] for r in rej] == ["missing_camera_info", "missing_tf_edge"]
    assert rej[0]["topic"] == "/boxi/hdr/left/camera_info"
    assert "'hdr_left'" in rej[1]["detail"] and rej[1]["file"] == "m0_tf_minimal.bag"
    assert rej[0]["file"] == "m0_hdr_left.bag"
    assert res.images == {"front": 10}


def test_missing_tf_edge_fails_naming_the_chain(tmp_path: Path) -> None:
    mission = write_mission(tmp_path, Mission(drop_edge="hdr_base"))
    with pytest.raises(MissingTransformError, match=r"from 'base' to 'hdr_front'"):
        ingest_recording(mission, tmp_path / "out", CFG)


def test_a_y_field_declared_at_xs_offset_rejects_every_sweep_naming_it(tmp_path: Path) -> None:
    """Was: y read x's bytes (numpy allows overlapping fields): 15 views cached, no reject."""
    m = Mission(field_offsets={"y": 0})
    res = ingest_recording(write_mission(tmp_path, m), tmp_path / "out", CFG)
    rej = [r for r in _rejects(res.index_dir) if r["topic"] == "/boxi/hesai/points_undistorted"]
    assert [r["reason"] for r in rej] == ["bad_pointcloud"] * len(lidar_stamps(m))
    assert [r["stamp_ns"] for r in rej] == lidar_stamps(m)
    assert rej[0]["file"] == "m0_hesai_undist.bag"
    assert "'x'" in rej[0]["detail"] and "'y'" in rej[0]["detail"] and "overlap" in rej[0]["detail"]
    assert res.sweeps == 0


def test_a_field_past_point_step_rejects_the_sweeps_not_the_recording(tmp_path: Path) -> None:
    m = Mission(field_offsets={"timestamp": 20})  # 8 bytes at 20 end at 28 > point_step 26
    res = ingest_recording(write_mission(tmp_path, m), tmp_path / "out", CFG)
    rej = [r for r in _rejects(res.index_dir) if r["reason"] == "bad_pointcloud"]
    assert len(rej) == len(lidar_stamps(m)) and "past point_step 26" in rej[0]["detail"]
    assert sum(res.images.values()) > 0  # the cameras are kept
