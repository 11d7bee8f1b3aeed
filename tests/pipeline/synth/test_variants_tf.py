"""TF and pose-source variants: on each, inspect decides what the variant's truth says (the
full runs under the written configurations are `m3gd bench variants --only tf`, slow)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from pipeline.inspect.config_out import build_config
from pipeline.inspect.decide import mismatches
from pipeline.inspect.recording import inspect_recording
from pipeline.synth.api import synthesize
from pipeline.synth.variants_tf import TF_VARIANTS, Truth, apply_tf_variant
from schemas.config import SynthConfig, TopicsConfig

IMAGE = TopicsConfig().image_topic("front")
DEFAULT = Truth({"odometry": TopicsConfig().odometry, "odom_frame": "odom", "base_frame": "base"},
                False, (TopicsConfig().lidar,), {IMAGE: "hdr_front"})


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small default mission (one camera, 1 s), written once."""
    root = tmp_path_factory.mktemp("tf_variants")
    synthesize(root, SynthConfig(seed=3, seconds=1.0, cameras=["front"], image_width=96,
                                 image_height=64, points_per_sweep=512, depth_maps=False),
               "corridor", "m")  # fmt: skip
    return root / "m"


def test_the_default_mission_decides_its_truth(clean: Path) -> None:
    assert mismatches(inspect_recording(clean).decisions, DEFAULT.pose, False, DEFAULT.lidars,
                      DEFAULT.camera_frames) == []  # fmt: skip


@pytest.mark.parametrize("name", list(TF_VARIANTS))
def test_inspect_decides_each_variants_truth(clean: Path, tmp_path: Path, name: str) -> None:
    mission = tmp_path / "m"
    shutil.copytree(clean, mission)
    apply_tf_variant(mission, name, IMAGE)
    truth = TF_VARIANTS[name].truth(DEFAULT)
    ins = inspect_recording(mission)
    assert mismatches(ins.decisions, truth.pose, truth.pose_ambiguous, truth.lidars,
                      truth.camera_frames) == [], [d.line() for d in ins.decisions]  # fmt: skip
    cfg, warnings = build_config(ins, mission)
    t = cfg.ingest.topics
    assert (t.odom_frame, t.base_frame) == (truth.pose["odom_frame"], truth.pose["base_frame"])
    assert any(w.startswith("AMBIGUOUS pose") for w in warnings) == truth.pose_ambiguous


def test_the_wheel_edge_sorting_first_is_not_the_pose(clean: Path, tmp_path: Path) -> None:
    """The measured failure: /tf holding base -> wheel_left_link (first by name) beside
    odom -> base wrote odom_frame wheel_left_link. The wheels are named as alternatives."""
    mission = tmp_path / "m"
    shutil.copytree(clean, mission)
    apply_tf_variant(mission, "tf_wheels", IMAGE)
    ins = inspect_recording(mission)
    assert next(e.child for e in ins.tf.edges if not e.static) == "wheel_left_link"
    (pose,) = [d for d in ins.decisions if d.what == "pose"]
    assert pose.chosen == "/tf odom->base" and not pose.ambiguous
    wheel = next(c for c in pose.candidates if c.name == "/tf base->wheel_left_link")
    assert "wheel_left_link is named as a joint or wheel" in wheel.evidence
    assert any("does not change" in ev for ev in wheel.evidence)


def test_the_cli_says_each_decision(clean: Path, tmp_path: Path) -> None:
    """In `--json`, the text output and the written configuration's comments."""
    import json

    from typer.testing import CliRunner

    from cli.app import app

    mission = tmp_path / "m"
    shutil.copytree(clean, mission)
    apply_tf_variant(mission, "odometry_disagrees", IMAGE)
    cfg = tmp_path / "c.yaml"
    out = CliRunner().invoke(app, ["inspect", str(mission), "--json", "--write-config", str(cfg)])
    assert out.exit_code == 0, out.output
    pose = json.loads(out.stdout)["decisions"][0]
    assert pose["what"] == "pose" and pose["ambiguous"] and len(pose["candidates"]) == 2
    assert any("DISAGREES" in e for e in pose["candidates"][0]["evidence"])
    text = cfg.read_text()
    assert "# AMBIGUOUS pose: /anymal/state_estimator/odometry" in text
    assert "# decided lidar: /boxi/hesai/points_undistorted" in text
    out = CliRunner().invoke(app, ["inspect", str(mission)])
    assert "ambiguous pose: /anymal/state_estimator/odometry (AMBIGUOUS" in out.output
