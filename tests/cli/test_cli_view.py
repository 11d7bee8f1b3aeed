"""CLI wiring of `m3gd view` and `m3gd report` over the tiny output (issue 20)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from cli.app import app
from schemas.config import M3GDConfig, config_to_dict
from tests.pipeline.tiny_output import tiny_output


@pytest.fixture(scope="module")
def cfg(tmp_path_factory: pytest.TempPathFactory) -> M3GDConfig:
    return tiny_output(tmp_path_factory)


def _yaml(cfg: M3GDConfig, tmp_path: Path) -> str:
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(config_to_dict(cfg)))
    return str(path)


def test_view_writes_the_file_and_says_how_to_open_it(cfg: M3GDConfig, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "v.rrd"
    result = CliRunner().invoke(app, ["-c", _yaml(cfg, tmp_path), "view", "-o", str(out),
                                      "--max-views", "5", "--spawn"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert out.stat().st_size > 0
    assert "kept the first 5 of" in text and "5 views of t_view" in text
    assert "no display here" in text and f"rerun {out}" in text


def test_view_of_an_unknown_camera_is_one_line(cfg: M3GDConfig, tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["-c", _yaml(cfg, tmp_path), "view", "--camera", "rear",
                                      "-o", str(tmp_path / "x.rrd")])
    assert result.exit_code == 1
    assert "no cache group for camera(s) ['rear']" in result.output
    assert "Traceback" not in result.output and not (tmp_path / "x.rrd").exists()


def test_report_writes_one_page(cfg: M3GDConfig, tmp_path: Path) -> None:
    out = tmp_path / "r.html"
    result = CliRunner().invoke(app, ["-c", _yaml(cfg, tmp_path), "report", "-o", str(out),
                                      "--no-plots"])
    assert result.exit_code == 0, result.output
    assert out.read_text().startswith("<!DOCTYPE html>") and "needs no server" in result.output
