"""Configuration refusals through the CLI: an empty or comment-only file, and a run that
would synthesize recordings nobody asked for."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from cli.app import app


def test_an_empty_config_is_refused_in_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("# nothing but a comment\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "config", "show"])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1
    assert f"{cfg}: an empty configuration" in result.output


def test_a_run_without_recordings_does_not_synthesize_by_omission(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    text = " ".join(result.output.split())
    assert result.exit_code == 2 and text.startswith("error: no recording to run on"), text
    assert "synthetic: true" in text and not (tmp_path / "out").exists()
    result = CliRunner().invoke(app, ["-c", str(cfg), "ingest", "--local"])
    assert result.exit_code == 2 and "no recording to run on" in result.output


def test_the_embedded_defaults_and_the_demo_ask_for_synthesis() -> None:
    shown = CliRunner().invoke(app, ["config", "show"])
    assert shown.exit_code == 0 and "synthetic: true" in shown.output
