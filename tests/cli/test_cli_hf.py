"""`m3gd synth --format hf-zarr` then `m3gd ingest` on the mission folder (format detected)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app


def test_synth_hf_then_ingest(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    runner = CliRunner()
    made = runner.invoke(app, ["synth", str(tmp_path / "rec"), "--seconds", "0.5",
                               "--format", "hf-zarr", "--mission", "m"])  # fmt: skip
    assert made.exit_code == 0, made.output
    mission = tmp_path / "rec" / "m"
    assert (mission / "data" / ".zgroup").is_file() and (mission / "images" / "hdr_front").is_dir()
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\ningest: {{out_height: 112, out_width: 168}}\n")
    done = runner.invoke(app, ["-c", str(cfg), "ingest", str(mission)])
    assert done.exit_code == 0, done.output
    assert (tmp_path / "out" / "index" / "m" / "images.parquet").is_file()
    assert "input format hf-zarr (Zarr v2), detected" in done.output + caplog.text
