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


def test_limit_prints_the_first_rows_and_says_how_many_are_left(tmp_path: Path) -> None:
    code, text = _run(tmp_path, "--json", "--limit", "3", "SELECT i FROM range(10) t(i)")
    lines = text.splitlines()
    assert code == 0 and [json.loads(line) for line in lines[:3]] == [{"i": 0}, {"i": 1}, {"i": 2}]
    assert lines[3:] == ["(7 more rows of 10 not printed: --limit 0 prints all, --out FILE "
                         "writes all)"]
    code, text = _run(tmp_path, "--json", "--limit", "0", "SELECT i FROM range(1500) t(i)")
    assert code == 0 and len(text.splitlines()) == 1500
    code, text = _run(tmp_path, "--json", "SELECT i FROM range(1500) t(i)")
    assert code == 0 and "(500 more rows of 1500 not printed" in text  # 1000 by default


def test_query_out_and_export_write_every_row(tmp_path: Path) -> None:
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    csv = tmp_path / "rows.csv"
    code, text = _run(tmp_path, "--out", str(csv), "SELECT i FROM range(2500) t(i)")
    assert code == 0 and text == f"{csv}: 2500 rows (csv)", text
    assert pacsv.read_csv(csv).num_rows == 2500
    cfg = tmp_path / "c.yaml"
    table = tmp_path / "rejects.parquet"
    result = CliRunner().invoke(app, ["-c", str(cfg), "stats", "export", "rejects",
                                      "--out", str(table)])
    assert result.exit_code == 0, result.output
    assert sorted(pq.read_table(table).column("reason").to_pylist()) == [
        "corrupt_jpeg", "empty_sweep", "x"]


def test_export_refuses_foreign_files_table_folders_and_names(tmp_path: Path) -> None:
    _run(tmp_path, "SELECT 1")  # writes the config and the output
    cfg = tmp_path / "c.yaml"
    mine = tmp_path / "notes.txt"
    mine.write_text("keep me")

    def export(*args: str) -> tuple[int, str]:
        result = CliRunner().invoke(app, ["-c", str(cfg), "stats", "export", *args])
        return result.exit_code, " ".join(result.output.split())

    code, text = export("rejects", "--out", str(mine))
    assert code == 2 and "m3gd did not write" in text and mine.read_text() == "keep me"
    code, text = export("rejects", "--out", str(tmp_path / "out" / "stats" / "x.parquet"))
    assert code == 2 and "inside the output's tables" in text
    code, text = export("rejects; COPY x TO 'y'", "--out", str(tmp_path / "y.parquet"))
    assert code == 2 and "not a table name" in text
    code, text = export("rejects", "--out", str(tmp_path / "y.json"), "--format", "json")
    assert code == 2 and "one of parquet, csv" in text


def test_ctrl_c_stops_the_query_with_exit_130(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        python_sigint: None) -> None:
    from tests.pipeline.analysis.test_query_sandbox import interrupt_once_running

    sent = interrupt_once_running(monkeypatch)
    code, text = _run(tmp_path, "SELECT count(*) FROM range(1000000000000) t(i) WHERE i % 7 = 3")
    assert sent and code == 130 and text == "error: interrupted: the query stopped", text


def test_no_escape_through_the_cli_from_a_folder_holding_tmp(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / ".tmp").mkdir()
    (tmp_path / ".tmp" / "secret.csv").write_text("a\nhidden-value\n")
    monkeypatch.chdir(tmp_path)
    for sql in ("SELECT * FROM read_csv('.tmp/secret.csv')", "SELECT * FROM glob('.tmp/*')",
                "COPY (SELECT 1) TO '.tmp/pwn.csv'"):
        code, text = _run(tmp_path, sql)
        assert code == 1 and "query refused" in text and "hidden-value" not in text, text
    assert [p.name for p in (tmp_path / ".tmp").iterdir()] == ["secret.csv"]


@pytest.mark.parametrize("sql", ["SELECT 1 AS a, 2 AS a", "SELECT 1 AS b, 2 AS a, 3 AS a"])
def test_json_of_duplicate_column_names_is_refused_naming_the_column(tmp_path: Path,
                                                                    sql: str) -> None:
    code, text = _run(tmp_path, "--json", sql)
    assert code == 2 and len(text.splitlines()) == 1
    assert "2 columns named 'a'" in text and "{" not in text


def test_duplicate_column_names_still_print_as_a_table(tmp_path: Path) -> None:
    code, text = _run(tmp_path, "SELECT 1 AS a, 2 AS a")
    assert code == 0 and "1" in text and "2" in text


def test_distinct_names_round_trip_every_value(tmp_path: Path) -> None:
    code, text = _run(tmp_path, "--json", "SELECT 1 AS a, 2 AS a2")
    assert code == 0 and json.loads(text) == {"a": 1, "a2": 2}
