"""The KITTI-360 source on the copy of a synthetic recording: detection, identity, the index,
faults as rejects naming file and line, layout errors, and inspect."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from pipeline.ingest.sources.base import DETECT_DEPTH, list_names
from pipeline.ingest.sources.kitti360 import Kitti360Layout, Kitti360Source, camera_folders
from schemas.errors import DataError
from schemas.recording_index import INDEX_TABLES, read_index_table, table_path
from tests.pipeline.ingest.sources.kitti360_kit import (
    INGEST,
    SEQ,
    bags_of,
    copy_of,
    kitti_root,
)

SRC = Kitti360Source()


def _rows(idx: Path, name: str) -> list[dict[str, object]]:
    rows: list[dict[str, object]] = read_index_table(table_path(idx, name),
                                                     INDEX_TABLES[name]).to_pylist()
    return rows


def test_claims_and_identity(tmp_path_factory: pytest.TempPathFactory) -> None:
    root = kitti_root(tmp_path_factory)
    assert SRC.claims(list_names(root, DETECT_DEPTH))
    assert not SRC.claims(list_names(bags_of(tmp_path_factory), DETECT_DEPTH))
    ident = SRC.identity(list_names(root))
    assert "calibration/perspective.txt" in ident
    assert f"data_3d_raw/{SEQ}/velodyne_points/timestamps.txt" in ident
    assert f"data_2d_raw/{SEQ}/image_00/data_rect/" in ident  # the folder, not its 23 PNGs
    assert not any(n.endswith(".png") or n.endswith(".bin") for n in ident)


def test_clean_index(tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:
    root = kitti_root(tmp_path_factory)
    res = SRC.ingest(root, tmp_path, INGEST, None, "clean")
    truth = json.loads((bags_of(tmp_path_factory) / "groundtruth" / "calibration.json")
                       .read_text())  # fmt: skip
    assert res.rejects == {} and res.unaccounted == {}
    assert res.images == {"front": 23, "left": 23} and res.sweeps == 20 and res.odometry == 23
    assert res.input_format.startswith("kitti360 (sequence 2013_05_28_drive_0000_sync")
    calib = {r["sensor"]: r for r in _rows(res.index_dir, "calibration")}
    for sensor in ("front", "left", "lidar"):
        np.testing.assert_allclose(np.reshape(calib[sensor]["T_base_sensor"], (4, 4)),
                                   truth["T_base_sensor"][sensor], atol=1e-12)  # fmt: skip
    assert calib["front"]["model"] == "pinhole" and calib["front"]["D"] == [0.0] * 5
    sweeps = _rows(res.index_dir, "sweeps")
    assert all(r["t_first_ns"] == r["t_last_ns"] == r["stamp_ns"] for r in sweeps)
    assert {r["time_field"] for r in sweeps} == {""}  # the header-stamp convention, declared
    assert sweeps[3]["file"] == f"data_3d_raw/{SEQ}/velodyne_points/data/0000000003.bin"
    acct = _rows(res.index_dir, "accounting")
    assert {r["topic"]: r["read"] for r in acct} == {"image_00": 23, "image_01": 23,
                                                     "velodyne_points": 20, "poses": 23}
    got = list(SRC.iter_sweeps(root, sweeps[:2]))
    assert got[1].xyz.shape == (sweeps[1]["n_valid"], 3)
    assert (got[1].t_ns == sweeps[1]["stamp_ns"]).all()


def _line(path: Path, i: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[i] = text
    path.write_text("\n".join(lines) + "\n")


def test_faults_become_rejects(tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:
    root = copy_of(tmp_path_factory, tmp_path)
    lay = Kitti360Layout.open(root)
    lay.frame_file("image_00", 3).unlink()
    png = lay.frame_file("image_00", 5)
    png.write_bytes(png.read_bytes()[:200])
    velo = lay.sensor_dir("velodyne_points") / "timestamps.txt"
    _line(velo, 6, velo.read_text().splitlines()[5])  # frame 6 repeats frame 5's stamp
    bin9 = lay.frame_file("velodyne_points", 9)
    bin9.write_bytes(bin9.read_bytes()[:30])
    _line(lay.sensor_dir("image_01") / "timestamps.txt", 2, "2024-05-29 16:26:39,8")
    res = SRC.ingest(root, tmp_path / "out", INGEST, None, "clean")
    assert res.rejects == {"missing_file": 1, "corrupt_jpeg": 1, "duplicate_stamp": 1,
                           "bad_pointcloud": 1, "undecodable_message": 1}  # fmt: skip
    assert res.unaccounted == {}
    assert res.images == {"front": 21, "left": 22} and res.sweeps == 18
    details = {r["reason"]: (r["file"], r["detail"]) for r in _rows(res.index_dir, "rejects")}
    assert details["missing_file"][0] == f"data_2d_raw/{SEQ}/image_00/data_rect/0000000003.png"
    assert "PNG data corrupt" in details["corrupt_jpeg"][1]
    assert "0000000009.bin: 30 bytes is not a whole number" in details["bad_pointcloud"][1]
    assert "image_01/timestamps.txt line 3: '2024-05-29 16:26:39,8'" in (
        details["undecodable_message"][1])
    acct = {r["topic"]: r for r in _rows(res.index_dir, "accounting")}
    assert (acct["image_00"]["read"], acct["image_00"]["kept"]) == (23, 21)


def test_layout_errors(tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:
    root = copy_of(tmp_path_factory, tmp_path)
    (root / "calibration" / "perspective.txt").unlink()
    with pytest.raises(DataError, match=r"calibration/perspective.txt: no such file"):
        SRC.ingest(root, tmp_path / "out", INGEST, None, "clean")
    shutil.copytree(root / "data_3d_raw" / SEQ, root / "data_3d_raw" / "other_sync")
    with pytest.raises(DataError, match=r"2 sequences \(2013_05_28_drive_0000_sync, other_sync"):
        Kitti360Layout.open(root)
    with pytest.raises(DataError, match="KITTI-360 has 2 perspective cameras"):
        camera_folders(["front", "left", "right"])
    assert camera_folders(["image_01"]) == {"image_01": "image_01"}
    assert camera_folders(["front", "left"]) == {"front": "image_00", "left": "image_01"}


def test_inspect(tmp_path_factory: pytest.TempPathFactory) -> None:
    rep = SRC.inspect(kitti_root(tmp_path_factory), time.perf_counter())
    assert rep.format == "kitti360 (sequence 2013_05_28_drive_0000_sync)"
    topics = {t.topic: t for t in rep.topics}
    assert topics["velodyne_points"].count == 20 and topics["poses"].count == 23
    assert abs((topics["image_00"].rate_hz or 0) - 10) < 0.5
    assert rep.cameras[0].image_sizes == ((240, 160),)
    assert rep.cameras[0].calibrations[0].distortion_model == "pinhole (rectified)"
    assert rep.clouds[0].convention.decided_by == "kitti360: no per-point time"
    assert set(rep.tf.frames) >= {"pose", "image_00", "image_01", "velodyne"}


def test_a_written_config_names_the_kitti360_format(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    """`inspect --write-config`'s mapping takes `ingest.format` from the source that claims the
    folder (was: `rosbag` for anything not in the HF layout)."""
    from pipeline.inspect.config_out import config_mapping
    from pipeline.inspect.recording import inspect_recording

    root = kitti_root(tmp_path_factory)
    mapping, warnings = config_mapping(inspect_recording(root), root)
    assert mapping["ingest"]["format"] == "kitti360"
    # the layout fixes LiDAR, poses and frames by file: no "no LiDAR configured", "no
    # odometry" or "not connected to the base frame" warning about a rig it does not declare
    assert warnings == [], warnings
    assert set(mapping["ingest"]["topics"]) == {"per_camera"}
