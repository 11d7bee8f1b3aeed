"""Configurations written from an inspection: valid by construction, the rig's keys."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.inspect.config_out import build_config, camera_templates, write_config
from pipeline.inspect.recording import inspect_recording
from schemas.config import TopicsConfig, load_config
from tests.pipeline.inspect.rigkit import own_rig, synth


def test_synthetic_recording_gives_the_grandtour_keys(tmp_path_factory: pytest.TempPathFactory,
                                                      tmp_path: Path) -> None:  # fmt: skip
    mission = synth(tmp_path_factory, "insp_ros", seconds=1.5, ros2=True)
    cfg, warnings = build_config(inspect_recording(mission), mission)
    assert warnings == []
    assert cfg.ingest.topics == TopicsConfig()  # the defaults are GrandTour's, found again
    assert cfg.ingest.cameras == ["front", "left", "right"]
    assert cfg.ingest.recordings == [mission.resolve()]
    write_config(cfg, tmp_path / "c.yaml", warnings)
    assert load_config(tmp_path / "c.yaml") == cfg


def test_hf_recording(tmp_path_factory: pytest.TempPathFactory) -> None:
    mission = synth(tmp_path_factory, "insp_hf", seconds=1.0, format="hf-zarr")
    ins = inspect_recording(mission)
    assert ins.format == "hf-zarr (Zarr v2)" and ins.tf.roots == ("base",)
    assert ins.clouds[0].time_field is None and ins.clouds[0].sweeps[0].points > 0
    cfg, warnings = build_config(ins, mission)
    assert cfg.ingest.format == "hf-zarr" and cfg.ingest.hf.camera_group == "hdr_{camera}"
    assert cfg.ingest.hf.lidar_group == "hesai_points_undistorted" and warnings == []


def test_own_rig_single_camera_and_second_lidar(tmp_path: Path) -> None:
    mission = own_rig(tmp_path / "rig")
    cfg, warnings = build_config(inspect_recording(mission), mission)
    t = cfg.ingest.topics
    assert cfg.ingest.cameras == ["front"]  # one camera outside the names: its literal topics
    assert (t.camera_image, t.camera_info, t.camera_frame) == (
        "/cam0/image_raw", "/cam0/camera_info", "cam0_optical")
    assert t.lidar == "/livox/lidar" or t.lidar == "/os/points"
    assert any("left out (one LiDAR feeds" in w for w in warnings)
    assert any("raw sensor_msgs/Image" in w for w in warnings)
    assert any("camera_info changes" in w for w in warnings)
    assert any("no nav_msgs/Odometry" in w or "no odometry" in w for w in warnings)
    assert any("'cam0_optical' is not connected" in w for w in warnings)


def test_template_prefers_the_largest_set() -> None:
    from pipeline.inspect.model import CameraReport

    def cam(topic: str, frame: str) -> CameraReport:
        return CameraReport(topic, "sensor_msgs/msg/CompressedImage",
                            topic.replace("image/compressed", "info"), frame, "jpeg", (), (),
                            False)  # fmt: skip

    keys, names = camera_templates([cam("/r/left/image/compressed", "left_opt"),
                                    cam("/r/right/image/compressed", "right_opt"),
                                    cam("/x/front/image/compressed", "front")], hf=False)
    assert names == ["left", "right"]
    assert keys == {"camera_image": "/r/{camera}/image/compressed",
                    "camera_info": "/r/{camera}/info", "camera_frame": "{camera}_opt"}
