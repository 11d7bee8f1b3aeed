"""`m3gd stats query` through the CLI: SQL that reaches files refused in one line (exit 1)
unless `--allow-files`; index tables by name; a missing table answered with the list."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
from tests.pipeline.analysis.test_query import _output


def _run(tmp_path: Path, *args: str) -> tuple[int, str]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {_output(tmp_path / 'out')}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "stats", "query", *args])
    return result.exit_code, result.output.strip()


@pytest.mark.parametrize("sql", ["COPY (SELECT 1) TO '{tmp}/x.csv'",
                                 "SELECT * FROM read_csv('/etc/passwd')",
                                 "ATTACH '{tmp}/a.db'", "INSTALL httpfs", "LOAD httpfs"])
def test_file_access_is_refused_in_one_line(tmp_path: Path, sql: str) -> None:
    code, text = _run(tmp_path, sql.format(tmp=tmp_path))
    assert code == 1 and len(text.splitlines()) == 1 and "Traceback" not in text, text
    assert text.startswith("error: query refused") or "query refused" in text, text
    assert "--allow-files" in text
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "a.db").exists()


def test_allow_files_lifts_it(tmp_path: Path) -> None:
    code, text = _run(tmp_path, "--allow-files", f"COPY (SELECT 1 AS one) TO '{tmp_path}/x.csv'")
    assert code == 0, text
    assert (tmp_path / "x.csv").read_text().split() == ["one", "1"]


def test_index_tables_by_name_and_missing_ones_listed(tmp_path: Path) -> None:
    code, text = _run(tmp_path, "--json", "SELECT recording, reason FROM rejects ORDER BY 2")
    assert code == 0, text
    assert [json.loads(line) for line in text.splitlines()] == [
        {"recording": "r1", "reason": "corrupt_jpeg"}, {"recording": "r2", "reason": "empty_sweep"},
        {"recording": "r2", "reason": "x"}]
    code, text = _run(tmp_path, "SELECT * FROM damage")
    assert code == 1 and len(text.splitlines()) == 1, text
    assert "tables here: alignment, clips, rejects, selection, view_stats" in text


def test_help_documents_allow_files_and_index_tables() -> None:
    text = " ".join(CliRunner().invoke(app, ["stats", "query", "--help"]).output.split())
    assert "--allow-files" in text and "external access off" in text
    for name in ("rejects:", "selection:", "images:"):
        assert name in text
