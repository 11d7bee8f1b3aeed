"""The "Bring your own robot" guide's runnable blocks: inspect, write a config, run with it."""

from __future__ import annotations

from pathlib import Path

import yaml

from tests.docs.runnable import guide, runnable_blocks
from tests.docs.test_runnable_docs import check, run_blocks


def test_own_robot_guide_runs(tmp_path: Path) -> None:
    blocks = runnable_blocks(guide("own_robot"))
    assert len(blocks) == 5
    out = check(run_blocks(blocks, tmp_path))
    assert "TF tree (parent -> child as written):" in out
    assert "m3gd run summary" in out
    # after the first stages: verify checks what is there, the report and the view are written
    report = (tmp_path / "out" / "report.html").read_text()
    assert "my_robot" in report and report.count("<section id=") >= 4, out
    assert "none corrupt" in out  # verify read what the first stages stored
    assert list((tmp_path / "out" / "view").glob("*.rrd")), out
    written = yaml.safe_load((tmp_path / "robot.yaml").read_text())
    assert written["ingest"]["topics"]["lidar"] == "/boxi/hesai/points_undistorted"
    # the point-time convention as the guide shows it: decided from the evidence, declared
    assert written["ingest"]["topics"]["lidar_point_time"] == {
        "field": "timestamp", "unit": "s", "reference": "absolute"}
    # the two-LiDAR example: both LiDARs take their own sweeps for the views
    rows = [line for line in out.splitlines() if "│ ok " in line]
    assert [r.split("│")[1].strip() for r in rows] == ["hesai", "livox"], out
