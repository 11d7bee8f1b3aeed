"""Inspection of synthetic ROS1 / ROS2 recordings and of a rig the generator does not make:
topics and counts from the indexes, the TF tree, LiDAR layout and point-time evidence,
cameras and their calibration changes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from rosbags.convert.converter import convert
from rosbags.typesys import Stores, get_typestore

from pipeline.inspect.model import TfEdge
from pipeline.inspect.recording import inspect_recording
from pipeline.inspect.tf import shape, tree_lines
from tests.pipeline.inspect.rigkit import own_rig, synth
from tests.pipeline.synthkit import gt_table


@pytest.fixture(scope="module")
def mission(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return synth(tmp_path_factory, "insp_ros", seconds=1.5, ros2=True)


def test_ros1_topics_counts_and_tf(mission: Path) -> None:
    ins = inspect_recording(mission)
    topics = {t.topic: t for t in ins.topics}
    sweeps = gt_table(mission, "sweeps")
    lidar = topics["/boxi/hesai/points_undistorted"]
    assert lidar.count == len(sweeps) and lidar.msgtype == "sensor_msgs/msg/PointCloud2"
    assert lidar.rate_hz == pytest.approx(10.0, rel=0.02) and lidar.n_gaps == 0
    assert ins.format == "rosbag1" and len(ins.files) == 6
    static = {(e.parent, e.child) for e in ins.tf.edges if e.static}
    assert ("box_base", "hesai_lidar") in static and ("hdr_base", "hdr_front") in static
    dynamic = {(e.parent, e.child) for e in ins.tf.edges if not e.static}
    assert dynamic == {("base", "odom")}  # GrandTour's upside-down odom edge, as written
    assert ins.tf.roots == ("base",) and not ins.tf.multiple_parents
    assert ins.odometry == (("/anymal/state_estimator/odometry", "odom", "base"),)


def test_ros1_cloud_and_camera_evidence(mission: Path) -> None:
    ins = inspect_recording(mission)
    (cloud,) = ins.clouds
    assert [(f.name, f.offset, f.dtype) for f in cloud.fields][-1] == ("timestamp", 18, "f8")
    assert cloud.point_step == 26 and cloud.time_field == "timestamp"
    assert cloud.time_dtype == "<f8" and cloud.sweep_period_s == pytest.approx(0.1, rel=0.01)
    seconds = next(u for u in cloud.units if u.unit == "s")
    assert 0.05 < seconds.span_s <= 0.1 and abs(seconds.offset_if_absolute_s) < 0.01
    assert cloud.convention.reference == "absolute" and cloud.convention.unit == "s"
    assert all(s.read_corrupt == 0 for s in cloud.sweeps)
    cams = {c.image_topic: c for c in ins.cameras}
    front = cams["/boxi/hdr/front/image_raw/compressed"]
    assert front.info_topic == "/boxi/hdr/front/camera_info" and front.frame_id == "hdr_front"
    assert front.image_sizes == ((168, 112),) and "jpeg" in front.encoding
    assert front.calibrations[0].distortion_model == "equidistant"
    assert not front.calibration_changes and len(front.calibrations) > 1


def test_ros2_mcap_and_sqlite_match_ros1(mission: Path, tmp_path: Path) -> None:
    ros1 = inspect_recording(mission)
    mcap = inspect_recording(mission / "ros2")
    db3 = tmp_path / "db3"
    convert(sorted(mission.glob("*.bag")), db3, "sqlite3", 9, None, "file", None,
            get_typestore(Stores.ROS2_HUMBLE), [], [], [], [])  # fmt: skip
    sqlite = inspect_recording(db3)
    for other in (mcap, sqlite):
        assert other.format == "rosbag2"
        assert [(t.topic, t.count, t.first_ns, t.last_ns) for t in other.topics] == [
            (t.topic, t.count, t.first_ns, t.last_ns) for t in ros1.topics]
        assert other.tf.edges == ros1.tf.edges
        assert other.clouds[0].fields == ros1.clouds[0].fields
        assert other.clouds[0].units == ros1.clouds[0].units
    json.dumps(mcap.as_dict())  # JSON-ready


def test_own_rig_evidence(tmp_path: Path) -> None:
    ins = inspect_recording(own_rig(tmp_path / "rig"))
    topics = {t.topic: t for t in ins.topics}
    assert topics["/livox/lidar"].count == 25 and topics["/livox/lidar"].n_gaps == 1
    assert topics["/livox/lidar"].gaps[0].seconds == pytest.approx(0.6)
    clouds = {c.topic: c for c in ins.clouds}
    livox = clouds["/livox/lidar"]
    assert livox.time_field == "timestamp" and livox.time_dtype == "<f8"
    ns = next(u for u in livox.units if u.unit == "ns")
    assert ns.span_s == pytest.approx(0.097, rel=1e-3)  # absolute ns: a 97 ms sweep
    assert abs(ns.offset_if_absolute_s) < 1e-6
    # ingest's inference: float64 absolute ns, not seconds, and not one point corrupt
    assert (livox.convention.unit, livox.convention.reference) == ("ns", "absolute")
    assert sum(s.read_corrupt for s in livox.sweeps) == 0
    assert all(abs(s.read_last_ns - s.read_first_ns - 97_000_000) < 2_000_000
               for s in livox.sweeps)
    ouster = clouds["/os/points"]
    assert ouster.time_dtype == "<u4" and ouster.fields[-1].datatype == 6
    us = next(u for u in ouster.units if u.unit == "us")
    assert us.span_s == pytest.approx(0.097) and us.offset_if_relative_s == 0.0
    (cam,) = ins.cameras
    assert cam.image_type == "sensor_msgs/msg/Image" and cam.encoding == "bgr8"
    assert cam.frame_id == "cam0_optical" and cam.calibration_changes
    assert {(c.width, c.height) for c in cam.calibrations} == {(64, 48), (32, 24)}
    assert ins.tf.roots == ("base_link",) and ins.tf.sampled == {"/tf_static": 1}


def test_tree_shape_roots_and_cycles() -> None:
    edges = [TfEdge("map", "odom", False, "/tf", 3), TfEdge("odom", "base", False, "/tf", 3),
             TfEdge("world", "base", True, "/tf_static", 1), TfEdge("a", "b", True, "/s", 1),
             TfEdge("b", "a", True, "/s", 1)]  # fmt: skip
    rep = shape(edges)
    assert rep.roots == ("map", "world") and rep.multiple_parents == {"base": ["odom", "world"]}
    lines = tree_lines(rep)
    assert "map -> odom  (dynamic, /tf)" in lines and "  odom -> base  (dynamic, /tf)" in lines
    assert any("(cycle)" in line for line in lines) and len(lines) == 5  # every edge once


def test_missing_path_is_named(tmp_path: Path) -> None:
    from schemas.errors import MissingInputError

    with pytest.raises(MissingInputError, match=re.escape(str(tmp_path / "nope"))):
        inspect_recording(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(MissingInputError, match=r"no ROS1 \.bag files"):
        inspect_recording(tmp_path / "empty")
