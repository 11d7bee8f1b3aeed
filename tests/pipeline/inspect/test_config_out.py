"""Configurations written from an inspection: valid by construction, the rig's keys."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from pipeline.inspect.config_cameras import camera_keys, camera_name, camera_templates
from pipeline.inspect.config_out import build_config, write_config
from pipeline.inspect.model import CameraReport
from pipeline.inspect.recording import inspect_recording
from schemas.config import TopicsConfig, load_config
from schemas.config_sections import PointTimeConfig
from tests.pipeline.inspect.rigkit import own_rig, synth


def test_synthetic_recording_gives_the_grandtour_keys(tmp_path_factory: pytest.TempPathFactory,
                                                      tmp_path: Path) -> None:  # fmt: skip
    mission = synth(tmp_path_factory, "insp_ros", seconds=1.5, ros2=True)
    cfg, warnings = build_config(inspect_recording(mission), mission)
    assert warnings == []
    # the defaults are GrandTour's, found again; the point time its evidence decided, declared
    hesai = PointTimeConfig(field="timestamp", unit="s", reference="absolute")
    assert cfg.ingest.topics == TopicsConfig(lidar_point_time=hesai)
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
    assert cfg.ingest.hf.lidar_group == "hesai_points_undistorted"
    # no per-point time field: nothing decided, auto stays (with its comment)
    assert cfg.ingest.topics.lidar_point_time == "auto"
    assert len(warnings) == 1 and "no per-point time field" in warnings[0]


def test_own_rig_single_camera_and_second_lidar(tmp_path: Path) -> None:
    mission = own_rig(tmp_path / "rig")
    cfg, warnings = build_config(inspect_recording(mission), mission)
    t = cfg.ingest.topics
    assert cfg.ingest.cameras == ["cam0"]  # named after its topic, its own topics
    assert (t.image_topic("cam0"), t.info_topic("cam0"), t.frame_of("cam0")) == (
        "/cam0/image_raw", "/cam0/camera_info", "cam0_optical")
    assert t.camera_image == TopicsConfig().camera_image  # the template is left alone
    # both LiDARs declared, the reference first (as many messages: the first by name, and
    # the decision says it is ambiguous); the packets carry the reference's only
    assert [(x.name, x.topic, x.frame) for x in t.lidar_rig()] == [
        ("livox_frame", "/livox/lidar", "livox_frame"), ("os_sensor", "/os/points", "os_sensor")]
    assert cfg.select.lidar is None and not cfg.select.merges()
    assert any("set select.lidar: [livox_frame, os_sensor]" in w for w in warnings)
    assert any(w.startswith("AMBIGUOUS lidar: /livox/lidar") for w in warnings)
    assert not any("sensor_msgs/Image" in w for w in warnings)  # raw images are read
    assert any("camera_info changes" in w and "follows" in w for w in warnings)
    assert any("no odometry" in w for w in warnings)
    assert any("'cam0_optical' is not connected" in w for w in warnings)
    # each LiDAR's convention, as inspect's evidence decided it, is declared
    assert [x.point_time for x in t.lidar_rig()] == [
        PointTimeConfig(field="timestamp", unit="ns", reference="absolute"),
        PointTimeConfig(field="t", unit="us", reference="first_point")]


def test_an_undecided_point_time_stays_auto_with_a_comment(tmp_path: Path) -> None:
    from dataclasses import replace

    from pipeline.inspect.model import Convention

    mission = own_rig(tmp_path / "rig")
    ins = inspect_recording(mission)
    undecided = Convention("auto: no convention fits", None, None, "span 3 s over 0.1 s sweeps")
    ins = replace(ins, clouds=tuple(replace(c, convention=undecided) for c in ins.clouds))
    cfg, warnings = build_config(ins, mission)
    assert [x.point_time for x in cfg.ingest.topics.lidar_rig()] == ["auto", "auto"]
    lines = [w for w in warnings if "point-time convention undecided" in w]
    assert len(lines) == 2 and all("span 3 s over 0.1 s sweeps" in w for w in lines)
    assert [w.split(":")[0] for w in lines] == ["LiDAR /livox/lidar", "LiDAR /os/points"]
    write_config(cfg, tmp_path / "c.yaml", warnings)
    text = (tmp_path / "c.yaml").read_text()
    assert f"# {lines[0]}\n" in text
    written = yaml.safe_load(text)["ingest"]["topics"]["lidars"]
    assert [sorted(v) for v in written.values()] == [["frame", "topic"]] * 2  # auto: default
    assert load_config(tmp_path / "c.yaml") == cfg


def cam(topic: str, frame: str, calibrated: bool = False) -> CameraReport:
    from pipeline.inspect.model import Calibration

    cals = (Calibration(0, "plumb_bob", 5, 64, 48, 50.0, 50.0, 32.0, 24.0),) if calibrated else ()
    return CameraReport(topic, "sensor_msgs/msg/CompressedImage",
                        topic.replace("image/compressed", "info"), frame, "jpeg", (), cals,
                        False)  # fmt: skip


def test_template_prefers_the_largest_set() -> None:
    keys, names = camera_templates([cam("/r/left/image/compressed", "left_opt"),
                                    cam("/r/right/image/compressed", "right_opt"),
                                    cam("/x/front/image/compressed", "front")], hf=False)
    assert names == ["left", "right"]
    assert keys == {"camera_image": "/r/{camera}/image/compressed",
                    "camera_info": "/r/{camera}/info", "camera_frame": "{camera}_opt"}


def test_every_camera_is_configured_under_its_own_name() -> None:
    cams = (cam("/r/left/image/compressed", "left_opt", True),
            cam("/r/right/image/compressed", "right_opt", True),
            cam("/x/front/image/compressed", "front", True),
            cam("/zed/left/image/compressed", "zed2i_left_optical", True),
            cam("/y/cam/image/compressed", "", True),  # no frame: left out, told
            cam("/z/cam/image/compressed", "z_optical"))  # no calibration: left out, told
    keys = camera_keys(cams, hf=False)
    assert keys.names == ["r_left", "r_right", "x_front", "zed_left"]  # after their topics
    own = keys.topics["per_camera"]
    assert own["zed_left"] == {"image": "/zed/left/image/compressed", "info": "/zed/left/info",
                                 "frame": "zed2i_left_optical"}
    assert [w.split(":")[0] for w in keys.warnings] == ["camera /y/cam/image/compressed",
                                                        "camera /z/cam/image/compressed"]
    # the same names fit one template: written as the template, no per-camera keys
    two = camera_keys((cam("/r/a_cam/image/compressed", "a_cam_optical", True),
                       cam("/r/b_cam/image/compressed", "b_cam_optical", True)), hf=False)
    assert two.names == ["a_cam", "b_cam"] and "per_camera" not in two.topics
    assert two.topics == {"camera_image": "/r/{camera}/image/compressed",
                          "camera_info": "/r/{camera}/info", "camera_frame": "{camera}_optical"}


@pytest.mark.parametrize(("topic", "frame", "name"), [
    ("/cam0/image_raw", "cam0_optical_frame", "cam0"),
    ("/cam0/image_raw", "/base/cam0_link", "cam0"),  # the topic's name, not the frame's
    ("/boxi/hdr/front/image_raw/compressed", "hdr_front", "hdr_front"),
    ("/gt_box/alphasense_driver_node/cam1/color/image/compressed", "cam1_sensor_frame",
     "alphasense_cam1"),
    ("/gt_box/zed2i/zed_node/left/image_rect_color/compressed", "zed2i_left_optical",
     "zed2i_left"),
    ("/image_raw", "cam9_optical", "cam9"),  # a topic naming nothing: the frame's
    ("/cam0/image_raw", "_optical", "cam0"),  # nothing left of the frame: the topic
    ("/a b/image_raw/compressed", "__x", "a_b"),
    ("/image_raw", "__x", "camera"),
])
def test_camera_name(topic: str, frame: str, name: str) -> None:
    assert camera_name(cam(topic, frame)) == name
