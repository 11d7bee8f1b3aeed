"""Inputs inspect must name in one line instead of configuring: files that are no bag, a LiDAR
topic without messages, PointCloud2 layouts that cannot be decoded."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml
from rosbags.rosbag1 import Writer

from pipeline.inspect.config_out import build_config, write_config
from pipeline.inspect.recording import inspect_recording
from schemas.errors import DataError
from tests.pipeline.ingest.bagkit import typestore
from tests.pipeline.inspect.rigkit import SWEEP_NS, T0, _cloud, livox_points

CLOUD_T = "sensor_msgs/msg/PointCloud2"
LIVOX = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 12, 7), ("timestamp", 18, 8)]


@pytest.mark.parametrize(("data", "why"), [
    (b"", "an empty file (0 bytes), not a bag"),
    (bytes(range(256)) * 4, "not a ROS1 bag: it does not start with"),
])  # fmt: skip
def test_a_file_that_is_no_bag_is_named_as_such(tmp_path: Path, data: bytes, why: str) -> None:
    (tmp_path / "m.bag").write_bytes(data)
    for target in (tmp_path / "m.bag", tmp_path):
        with pytest.raises(DataError, match=f"^m.bag: {re.escape(why)}"):
            inspect_recording(target)


def test_a_cli_run_on_no_bag_writes_no_config(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cli.app import app

    (tmp_path / "m.bag").write_bytes(b"")
    out = CliRunner().invoke(app, ["inspect", str(tmp_path / "m.bag"), "--write-config",
                                   str(tmp_path / "c.yaml")])  # fmt: skip
    assert out.exit_code != 0 and "not a bag" in out.output and "rosbag1" not in out.output
    assert "Traceback" not in out.output and not (tmp_path / "c.yaml").exists()


def _bad_clouds(path: Path, empty_only: bool = False) -> Path:
    """A bag with an empty LiDAR topic and (unless `empty_only`) a good cloud and three whose
    layout cannot be decoded: a field past point_step, a point_step smaller than x, y, z, a
    field of 10^6 values."""
    ts = typestore()
    with Writer(path) as w:
        conns: dict[str, Any] = {}

        def put(topic: str, msg: Any, stamp: int) -> None:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, CLOUD_T, typestore=ts)
            w.write(conns[topic], stamp, ts.serialize_ros1(msg, CLOUD_T))

        w.add_connection("/empty/points", CLOUD_T, typestore=ts)
        for i in range(0 if empty_only else 4):
            st = T0 + i * SWEEP_NS
            pts = livox_points(st)
            put("/ok/points", _cloud(ts, st, "livox_frame", LIVOX, 26, pts, 200), st)
            put("/past/points", _cloud(ts, st, "a", [*LIVOX[:4], ("timestamp", 30, 8)], 26, pts,
                                       200), st)  # fmt: skip
            put("/small/points", _cloud(ts, st, "b", LIVOX, 8, pts[:1600], 200), st)
            wide = _cloud(ts, st, "c", LIVOX, 26, pts, 200)
            wide.fields[3].count = 10**6
            put("/count/points", wide, st)
    return path


def test_undecodable_clouds_and_an_empty_topic_are_named_not_configured(tmp_path: Path) -> None:
    bag = _bad_clouds(tmp_path / "m.bag")
    ins = inspect_recording(bag)
    errors = {c.topic: c.error for c in ins.clouds}
    assert "past point_step 26" in str(errors["/past/points"])
    assert "past point_step 8" in str(errors["/small/points"])
    assert "1000000 x f4" in str(errors["/count/points"])
    cfg, warnings = build_config(ins, bag)
    assert cfg.ingest.topics.lidar == "/ok/points"  # the only readable one, a single LiDAR
    named = {w.split(":")[0] for w in warnings if w.startswith("LiDAR /")}
    assert named == {"LiDAR /empty/points", "LiDAR /past/points", "LiDAR /small/points",
                     "LiDAR /count/points"}  # fmt: skip
    assert all("\n" not in w for w in warnings)


def test_an_empty_only_lidar_writes_no_empty_key(tmp_path: Path) -> None:
    bag = _bad_clouds(tmp_path / "m.bag", empty_only=True)
    cfg, warnings = build_config(inspect_recording(bag), bag)
    write_config(cfg, tmp_path / "c.yaml", warnings)
    topics = yaml.safe_load((tmp_path / "c.yaml").read_text())["ingest"].get("topics", {})
    assert "lidar_frame" not in topics and "lidar" not in topics and "" not in topics.values()
    assert any(w.startswith("LiDAR /empty/points: no messages") for w in warnings)
