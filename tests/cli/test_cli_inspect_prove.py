"""`m3gd inspect --write-config` proves its decisions (default) or not (`--no-verify`): the
scores in `--json`, the text and the written comments; every candidate failing exits non-zero
with the configuration written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
from tests.pipeline.inspect.provekit import FRONT, FRONT_INFO, restamped, variant


@pytest.fixture(scope="module")
def wheels(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return variant(tmp_path_factory, "tf_wheels")


def test_no_verify_skips_the_proof(wheels: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    out = CliRunner().invoke(app, ["inspect", str(wheels), "--write-config", str(cfg),
                                   "--no-verify", "--json"])  # fmt: skip
    assert out.exit_code == 0, out.output
    assert json.loads(out.output)["proof"] is None
    assert "| geometry:" not in cfg.read_text()
    text = CliRunner().invoke(app, ["inspect", str(wheels), "--write-config", str(cfg),
                                    "--no-verify"])  # fmt: skip
    assert "geometry: not proven (--no-verify)" in text.output


@pytest.mark.slow
def test_json_text_and_config_carry_the_scores(wheels: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    out = CliRunner().invoke(app, ["inspect", str(wheels), "--write-config", str(cfg), "--json"])
    assert out.exit_code == 0, out.output
    proof = json.loads(out.output)["proof"]
    pose = next(d for d in proof["decisions"] if d["what"] == "pose")
    assert pose["status"] == "proven" and pose["kept"] == "/tf odom->base"
    verdicts = {c["name"]: (c["verdict"], c["score"], c["z"]) for c in pose["candidates"]}
    assert verdicts["/tf odom->base"][0] == "ok" and verdicts["/tf odom->base"][2] > 4
    assert verdicts["/tf base->wheel_left_link"][0] == "failed"
    assert all(isinstance(s, float) for _, s, _ in verdicts.values())
    assert proof["seconds"] > 0 and pose["line"].startswith("geometry pose: proven")
    written = cfg.read_text()
    assert "# decided pose: /tf odom->base" in written and "| geometry: proven" in written
    text = CliRunner().invoke(app, ["inspect", str(wheels), "--write-config", str(cfg)])
    assert text.exit_code == 0 and "geometry pose: proven" in text.output
    assert "geometry proof:" in text.output


@pytest.mark.slow
def test_every_candidate_failing_exits_non_zero_unless_no_verify(
        tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:  # fmt: skip
    mission = restamped(tmp_path_factory, "both_frames_wrong",
                        {FRONT: "hdr_left", FRONT_INFO: "hdr_right"})
    cfg = tmp_path / "c.yaml"
    out = CliRunner().invoke(app, ["inspect", str(mission), "--write-config", str(cfg)])
    assert out.exit_code == 1, out.output
    assert "geometry disagrees for every candidate of" in out.output
    assert cfg.is_file() and "geometry disagrees for every candidate" in cfg.read_text()
    skip = CliRunner().invoke(app, ["inspect", str(mission), "--write-config", str(cfg),
                                    "--no-verify"])  # fmt: skip
    assert skip.exit_code == 0, skip.output
