"""`m3gd inspect`: tables, --json, one-line errors, and a written configuration that
`m3gd run --local` accepts as it is and that keeps the views a default run keeps."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml
from typer.testing import CliRunner

from cli.app import app
from pipeline.synth.api import synthesize
from pipeline.synth.variants_rig import (
    POSE_COV_T,
    POSE_T,
    TEN_CAMERAS,
    odometry_as,
    rig_topics,
    to_raw_images,
)
from schemas.config import SynthConfig, TopicsConfig, load_config
from tests.pipeline.inspect.rigkit import SMALL, synth

RUN = ["run", "--local", "--only", "ingest", "--only", "select", "--allow-empty"]


@pytest.fixture(scope="module")
def mission(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return synth(tmp_path_factory, "insp_cli", seconds=1.0, cameras=["front", "left"])


def test_tables_and_json(mission: Path) -> None:
    out = CliRunner().invoke(app, ["inspect", str(mission)])
    assert out.exit_code == 0, out.output
    assert "/boxi/hesai/points_undistorted" in out.output
    assert "box_base -> hesai_lidar" in out.output
    assert "time field: timestamp <f8" in out.output
    data = json.loads(CliRunner().invoke(app, ["inspect", str(mission), "--json"]).stdout)
    assert {t["topic"] for t in data["topics"]} >= {"/tf_static", "/tf"}
    assert data["clouds"][0]["time_field"] == "timestamp" and data["format"] == "rosbag1"


def test_missing_path_is_one_line_and_a_damaged_index_a_note(tmp_path: Path) -> None:
    out = CliRunner().invoke(app, ["inspect", str(tmp_path / "nope")])
    assert out.exit_code == 2 and out.output.count("\n") == 1
    assert str(tmp_path / "nope") in out.output
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 64)
    out = CliRunner().invoke(app, ["inspect", str(bad)])  # read as ingest would: sequentially
    assert out.exit_code == 0, out.output
    assert "note bad.bag: index unreadable" in out.output


def test_refuses_to_overwrite_a_foreign_file(mission: Path, tmp_path: Path) -> None:
    mine = tmp_path / "mine.yaml"
    mine.write_text("output_dir: precious\n")
    out = CliRunner().invoke(app, ["inspect", str(mission), "--write-config", str(mine)])
    assert out.exit_code == 2 and "did not write" in out.output
    assert mine.read_text() == "output_dir: precious\n"


def _views(out: Path) -> int:
    (rec,) = [p for p in (out / "index").iterdir() if p.is_dir()]
    table = pq.read_table(rec / "selection.parquet")
    return sum(1 for status in table.column("status").to_pylist() if status != "rejected")


def test_written_config_runs_and_keeps_the_default_views(
        mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    written = tmp_path / "inspected.yaml"
    out = CliRunner().invoke(app, ["inspect", str(mission), "--write-config", str(written)])
    assert out.exit_code == 0, out.output
    assert yaml.safe_load(written.read_text())["ingest"]["cameras"] == ["front", "left"]
    small = {"ingest": {"out_height": 56, "out_width": 84}}
    default = tmp_path / "default.yaml"
    default.write_text(yaml.safe_dump({"output_dir": "out_default", "ingest": {
        "recordings": [str(mission)], **small["ingest"], "cameras": ["front", "left"]}}))
    res = CliRunner().invoke(app, ["-c", str(default), *RUN])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["-c", str(written), *RUN])  # as written: output_dir out
    assert res.exit_code == 0, res.output
    assert _views(tmp_path / "out") == _views(tmp_path / "out_default") > 0


@pytest.mark.parametrize("rig", ["ten_cameras", "named_raw"])
def test_written_config_of_a_rig_keeps_the_views_of_its_own_config(
        rig: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """Cameras outside the templates (GrandTour's ten; two named ones with raw bgr8/bayer
    images): the written config names every camera with its own topics and frame, and keeps
    >= 0.95 of the views the hand-written config keeps."""
    monkeypatch.chdir(tmp_path)
    cams = list(TEN_CAMERAS) if rig == "ten_cameras" else ["hdr_mid", "stereo_left"]
    own = rig_topics(cams)
    synthesize(tmp_path, SynthConfig(seed=2, cameras=cams, seconds=1.0,
                                     **{**SMALL, "image_width": 96, "image_height": 64}),
               "corridor", "m", TopicsConfig(per_camera=own))  # fmt: skip
    mission = tmp_path / "m"
    if rig == "named_raw":  # every camera's images become sensor_msgs/Image
        to_raw_images(mission, "bayer_rggb8")
        own = {c: t.model_copy(update={"image": str(t.image).removesuffix("/compressed")})
               for c, t in own.items()}  # fmt: skip
    written = tmp_path / "inspected.yaml"
    out = CliRunner().invoke(app, ["inspect", str(mission), "--write-config", str(written)])
    assert out.exit_code == 0, out.output
    ingest = load_config(written).ingest
    # named after its topic: its last two naming segments (`/rig/hdr_front/image` beside
    # `/gt_box/zed2i/...`: rig_hdr_front), less a namespace every camera shares (`/rig/`)
    names = {c: f"rig_{c}" if rig == "ten_cameras" and c.startswith("hdr_") else c
             for c in cams}  # fmt: skip
    assert sorted(ingest.cameras) == sorted(names.values())
    for c in cams:  # a template or its own keys: the camera's topics and frame
        t, n = ingest.topics, names[c]
        assert (t.image_topic(n), t.info_topic(n), t.frame_of(n)) == (
            own[c].image, own[c].info, own[c].frame)
    assert not [line for line in written.read_text().splitlines() if line.startswith("#")
                and ("left out" in line or "not read" in line)]
    small = {"out_height": 42, "out_width": 56}
    clean = tmp_path / "clean.yaml"
    clean.write_text(yaml.safe_dump({"output_dir": "out_clean", "ingest": {
        "recordings": [str(mission)], "cameras": cams, **small,
        "topics": {"per_camera": {c: t.model_dump() for c, t in own.items()}}}}))
    res = CliRunner().invoke(app, ["-c", str(clean), *RUN])
    assert res.exit_code == 0, res.output
    data = yaml.safe_load(written.read_text())
    data["ingest"].update(small)
    written.write_text(yaml.safe_dump(data))
    res = CliRunner().invoke(app, ["-c", str(written), *RUN])
    assert res.exit_code == 0, res.output
    kept, base = _views(tmp_path / "out"), _views(tmp_path / "out_clean")
    assert base >= 5 * len(cams) and kept >= 0.95 * base


@pytest.mark.parametrize("msgtype", [POSE_T, POSE_COV_T])
def test_written_config_of_pose_odometry_keeps_the_default_views(
        mission: Path, msgtype: str, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """Odometry as PoseStamped / PoseWithCovarianceStamped: inspect finds it and the body
    frame, and the written config keeps every view of the nav_msgs/Odometry recording."""
    monkeypatch.chdir(tmp_path)
    small = {"out_height": 42, "out_width": 56, "cameras": ["front", "left"]}
    default = tmp_path / "default.yaml"
    default.write_text(yaml.safe_dump({"output_dir": "out_default", "ingest": {
        "recordings": [str(mission)], **small}}))
    res = CliRunner().invoke(app, ["-c", str(default), *RUN])
    assert res.exit_code == 0, res.output
    posed = tmp_path / mission.name
    shutil.copytree(mission, posed)
    assert odometry_as(posed, msgtype) > 0
    written = tmp_path / "inspected.yaml"
    out = CliRunner().invoke(app, ["inspect", str(posed), "--write-config", str(written)])
    assert out.exit_code == 0, out.output
    cfg = load_config(written)
    assert cfg.ingest.topics.odometry == "/anymal/state_estimator/odometry"
    assert cfg.ingest.topics.base_frame == "base"
    assert "names no child frame" in written.read_text()
    data = yaml.safe_load(written.read_text())
    data["ingest"].update(small)
    written.write_text(yaml.safe_dump(data))
    res = CliRunner().invoke(app, ["-c", str(written), *RUN])
    assert res.exit_code == 0, res.output
    assert _views(tmp_path / "out") == _views(tmp_path / "out_default") > 0


def test_a_write_config_cut_by_a_full_disk_leaves_nothing_and_the_next_one_writes(
        mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Was: a kill or a full disk at the write left a 0-byte file, which the next
    `--write-config` refused to replace. Now the file is written whole or not at all."""
    import errno
    import os

    written = tmp_path / "c.yaml"

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with monkeypatch.context() as patch:
        patch.setattr(os, "fsync", full)
        out = CliRunner().invoke(app, ["inspect", str(mission), "--write-config", str(written)])
    assert out.exit_code == 1 and "No space left on device" in out.output, out.output
    assert "Traceback" not in out.output and list(tmp_path.iterdir()) == []
    written.write_text("")  # what a write cut before this left: nothing to lose
    out = CliRunner().invoke(app, ["inspect", str(mission), "--write-config", str(written)])
    assert out.exit_code == 0, out.output
    assert load_config(written).ingest.recordings == [mission]
