"""CLI safety (issue 16): paths stay in their roots, empty runs fail, locks can be broken."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from bench.support.fuzz_cases import chunk_spans
from cli.app import app
from pipeline.run.lock import LOCK_NAME
from tests.pipeline.ingest.bagkit import Mission, write_mission


def _one_line(text: str) -> str:
    return " ".join(text.split())


def test_synth_mission_outside_its_folder_is_refused_before_any_work(tmp_path: Path) -> None:
    """Was: `m3gd synth OUT --mission ../x` wrote (and could rmtree) outside OUT."""
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "keep.txt").write_text("mine")
    for name in ("../x", "/abs/x", "..", "__zarr"):
        result = CliRunner().invoke(app, ["synth", str(tmp_path / "out"), "--mission", name,
                                          "--seconds", "0.2"])  # fmt: skip
        assert result.exit_code == 2, result.output
        assert "mission name" in result.output and "Traceback" not in result.output
    assert (tmp_path / "x" / "keep.txt").read_text() == "mine"
    assert not (tmp_path / "out").exists()


def test_recording_path_ending_in_dotdot_is_refused(tmp_path: Path) -> None:
    """Was: a recording named '..' failed inside zarr."""
    mission = tmp_path / "m" / "sub"
    mission.mkdir(parents=True)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "ingest", str(mission / "..")])
    assert result.exit_code == 2, result.output
    assert "folder name '..'" in _one_line(result.output)
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\ningest: {{recordings: ['{mission}/..']}}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert result.exit_code == 2 and "folder name '..'" in _one_line(result.output)
    assert not (tmp_path / "out").exists()


def test_run_without_any_usable_view_fails_saying_why(tmp_path: Path) -> None:
    """Was: exit 0 with zero usable views when the LiDAR bag is unreadable."""
    mission = write_mission(tmp_path, Mission(points=300))
    bag = mission / "m0_hesai_undist.bag"
    data = bytearray(bag.read_bytes())
    for _, data_at, _ in chunk_spans(bytes(data)):  # every chunk garbled, the index intact
        data[data_at + 8 : data_at + 40] = bytes(range(32))
    bag.write_bytes(bytes(data))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\n"
                   f"ingest: {{recordings: ['{mission}'], cameras: [front], "
                   f"out_height: 28, out_width: 42}}\n")  # fmt: skip
    args = ["-c", str(cfg), "run", "--local", "--only", "ingest", "--only", "select"]
    result = CliRunner().invoke(app, args)
    text = _one_line(result.output)
    assert result.exit_code == 1, result.output
    assert "recording m0: no usable view (10 view(s): no_sweep 10)" in text
    assert "ingest: damaged_region" in text and "--allow-empty" in text
    result = CliRunner().invoke(app, [*args, "--allow-empty"])
    assert result.exit_code == 0, result.output


def test_unlock_and_break_lock_for_a_lock_of_another_host(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    holder = {"host": "elsewhere.example", "pid": 7, "started_unix_s": 1.0}
    (out / LOCK_NAME).write_text(json.dumps(holder))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {out}\ningest: {{recordings: []}}\nsynth: {{scenes: []}}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert result.exit_code == 1
    assert f"m3gd unlock {out}" in _one_line(result.output)
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local", "--break-lock"])
    assert result.exit_code == 0, result.output
    (out / LOCK_NAME).write_text(json.dumps(holder))
    result = CliRunner().invoke(app, ["unlock", str(out)])
    assert result.exit_code == 0 and "elsewhere.example" in result.output
    assert not (out / LOCK_NAME).exists()
