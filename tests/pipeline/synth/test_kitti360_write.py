"""The KITTI-360 copy of a synthetic recording holds the generator's ground truth.

Calibration against the rig's true transforms, stamps to the nanosecond, every sweep's points,
poses against the true trajectory, and the undistorted PNGs against the raw fisheye images.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from packets.poses import interpolate_poses, invert_T, rot_to_quat
from pipeline.ingest.sources.kitti360_calib import (
    parse_cam_to_pose,
    parse_perspective,
    parse_poses,
    parse_rigid_file,
    parse_timestamps,
    parse_velodyne,
)
from pipeline.synth.api import synthesize
from pipeline.synth.groundtruth import read_poses
from pipeline.synth.kitti360_write import bags_to_kitti360, format_stamp
from schemas.config import SynthConfig, TopicsConfig
from tests.pipeline.synthkit import RECORDINGS, SMALL

SEQ = "2013_05_28_drive_0000_sync"
CAMS = ["front", "left"]


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, int]]:
    """(bag mission folder, KITTI-360 root, counts) of the 'clean' recording."""
    tmp = tmp_path_factory.mktemp("kitti_write")
    cfg = SynthConfig(seed=3, scenes=["corridor"], **{**SMALL, **RECORDINGS["clean"]})
    mission = synthesize(tmp / "bags", cfg, "corridor", "clean").mission_dir
    root = tmp / "kitti360"
    counts = bags_to_kitti360(sorted(mission.glob("*.bag")), root, TopicsConfig(), CAMS, SEQ)
    return mission, root, counts


def read_messages(bag: Path, topic: str) -> list[Any]:
    """Every message of `topic` in one bag, deserialized."""
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]


def _text(root: Path, rel: str) -> str:
    return (root / rel).read_text()


def test_format_stamp_round_trips() -> None:
    for ns in (0, 1_717_000_000_000_000_001, 1_369_730_762_904_069_733):
        assert parse_timestamps(format_stamp(ns) + "\n", "t")[0] == ns


def test_calibration_is_the_rigs(made: tuple[Path, Path, dict[str, int]]) -> None:
    mission, root, _ = made
    truth = json.loads((mission / "groundtruth" / "calibration.json").read_text())
    T = {k: np.asarray(v) for k, v in truth["T_base_sensor"].items()}
    to_pose = parse_cam_to_pose(_text(root, "calibration/calib_cam_to_pose.txt"), "c")
    np.testing.assert_allclose(to_pose["image_00"], T["front"], atol=1e-12)
    np.testing.assert_allclose(to_pose["image_01"], T["left"], atol=1e-12)
    velo = parse_rigid_file(_text(root, "calibration/calib_cam_to_velo.txt"), "v")
    np.testing.assert_allclose(velo, invert_T(T["lidar"]) @ T["front"], atol=1e-12)
    persp = parse_perspective(_text(root, "calibration/perspective.txt"), "p")
    for name, cam in zip(("image_00", "image_01"), CAMS, strict=True):
        c = persp[name]
        raw = truth["cameras"][cam]
        assert (c.width, c.height) == (raw["width"], raw["height"])
        assert c.P_rect[:, 3].tolist() == [0, 0, 0] and (c.R_rect == np.eye(3)).all()
        assert 0.3 < c.K[0, 0] / raw["K"][0][0] < 1.0  # a wider pinhole view of the fisheye


def test_stamps_and_sweeps_are_the_bags(made: tuple[Path, Path, dict[str, int]]) -> None:
    mission, root, counts = made
    images = pq.read_table(mission / "groundtruth" / "images.parquet").to_pylist()
    for name, cam in zip(("image_00", "image_01"), CAMS, strict=True):
        stamps = parse_timestamps(_text(root, f"data_2d_raw/{SEQ}/{name}/timestamps.txt"), name)
        want = [r["header_stamp_ns"] for r in images if r["camera"] == cam]
        assert stamps.tolist() == want and counts[name] == len(want) > 15
    velo = f"data_3d_raw/{SEQ}/velodyne_points"
    sweeps = pq.read_table(mission / "groundtruth" / "sweeps.parquet").to_pylist()
    stamps = parse_timestamps(_text(root, f"{velo}/timestamps.txt"), "velo")
    assert stamps.tolist() == [r["stamp_ns"] for r in sweeps]  # the first point's time
    clouds = read_messages(mission / "clean_hesai_undist.bag", TopicsConfig().lidar)
    assert len(clouds) == counts["velodyne_points"] == len(sweeps)
    for i in (0, len(sweeps) - 1):
        xyz, refl = parse_velodyne((root / velo / "data" / f"{i:010d}.bin").read_bytes(), "b")
        assert xyz.shape[0] == sweeps[i]["n_points"]
        raw = np.frombuffer(bytes(clouds[i].data), dtype=np.dtype(
            {"names": ["x", "y", "z", "intensity"], "formats": ["<f4"] * 4,
             "offsets": [0, 4, 8, 12], "itemsize": int(clouds[i].point_step)}))  # fmt: skip
        np.testing.assert_array_equal(xyz[:, 0], raw["x"])
        np.testing.assert_array_equal(refl, raw["intensity"])


def test_poses_follow_the_trajectory(made: tuple[Path, Path, dict[str, int]]) -> None:
    mission, root, _ = made
    frames, T = parse_poses(_text(root, f"data_poses/{SEQ}/poses.txt"), "poses.txt")
    stamps = parse_timestamps(_text(root, f"data_2d_raw/{SEQ}/image_00/timestamps.txt"), "t")
    assert 15 < frames.size == stamps.size  # odometry covers every frame of this recording
    t, T_true = read_poses(mission / "groundtruth")
    quats = np.array([rot_to_quat(R) for R in T_true[:, :3, :3]])
    ref = interpolate_poses(t, T_true[:, :3, 3], quats, stamps[frames], 10**9)
    assert ref.ok.all()
    # the bag's 20 Hz odometry interpolated at each frame's own stamp: within 1 mm of the truth
    # (a frame off by one would be ~8 cm away at 0.8 m/s)
    assert np.abs(T[:, :3, 3] - ref.T[:, :3, 3]).max() < 1e-3
    assert np.abs(T[:, :3, :3] - ref.T[:, :3, :3]).max() < 3e-3
    cam_frames, cam = parse_poses(_text(root, f"data_poses/{SEQ}/cam0_to_world.txt"), "c", 16)
    to_pose = parse_cam_to_pose(_text(root, "calibration/calib_cam_to_pose.txt"), "c")
    assert cam_frames.tolist() == frames.tolist()
    np.testing.assert_allclose(cam, T @ to_pose["image_00"], atol=1e-12)


def test_png_is_the_undistorted_fisheye(made: tuple[Path, Path, dict[str, int]]) -> None:
    mission, root, _ = made
    truth = json.loads((mission / "groundtruth" / "calibration.json").read_text())["cameras"]
    K, D = np.asarray(truth["front"]["K"]), np.asarray(truth["front"]["D"])
    P = parse_perspective(_text(root, "calibration/perspective.txt"), "p")["image_00"]
    jpeg = bytes(read_messages(mission / "clean_hdr_front.bag",
                               TopicsConfig().image_topic("front"))[0].data)
    raw = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE).astype(float)
    png = cv2.imread(str(root / f"data_2d_raw/{SEQ}/image_00/data_rect/{0:010d}.png"),
                     cv2.IMREAD_GRAYSCALE).astype(float)  # fmt: skip
    assert png.shape == raw.shape
    v, u = np.mgrid[20 : P.height - 20 : 3, 20 : P.width - 20 : 3]
    rays = np.stack([(u - P.K[0, 2]) / P.K[0, 0], (v - P.K[1, 2]) / P.K[1, 1]], -1)
    fish = cv2.fisheye.distortPoints(rays.reshape(-1, 1, 2), K, D.reshape(1, 4)).reshape(-1, 2)
    inside = (fish >= 0).all(1) & (fish[:, 0] < raw.shape[1] - 1) & (fish[:, 1] < raw.shape[0] - 1)
    fu, fv = np.round(fish[inside]).astype(int).T
    same = np.abs(png[v.ravel()[inside], u.ravel()[inside]] - raw[fv, fu]).mean()
    shifted = np.abs(png[v.ravel()[inside], u.ravel()[inside]] - raw[fv, np.clip(fu + 6, 0,
                     raw.shape[1] - 1)]).mean()  # fmt: skip
    assert inside.sum() > 1000 and same < 0.5 * shifted, (same, shifted)
