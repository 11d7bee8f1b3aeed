"""`stats query`'s sandbox closed: run from a working folder that holds `.tmp/` (DuckDB's
default spill folder, on its default allow-list), SQL reads, lists and writes nothing there
nor `:memory:.wal`; Ctrl-C stops a query within a second; first rows and row counts; export
by our writer; DuckDB's hint lines kept."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

from pipeline.analysis.query import Interrupted, close, connect, error_line, export, head, query
from schemas.errors import DataError
from tests.pipeline.analysis.test_query import _output

ESCAPES = ["SELECT * FROM read_csv('.tmp/secret.csv')",
           "SELECT * FROM glob('.tmp/*')",
           "COPY (SELECT 1 AS one) TO '.tmp/pwn.csv'",
           "COPY (SELECT 1 AS one) TO ':memory:.wal'",
           "SELECT * FROM read_text(':memory:.wal')",
           "SET enable_external_access = true",
           "SET allowed_directories = ['.tmp']",
           "SET temp_directory = '.tmp'"]


@pytest.fixture
def in_folder_with_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working folder holding `.tmp/secret.csv` and `:memory:.wal`."""
    work = tmp_path / "work"
    (work / ".tmp").mkdir(parents=True)
    (work / ".tmp" / "secret.csv").write_text("a\nhidden-value\n")
    (work / ":memory:.wal").write_text("wal\n")
    monkeypatch.chdir(work)
    return work


@pytest.mark.parametrize("sql", ESCAPES)
def test_no_escape_from_a_folder_holding_tmp(in_folder_with_tmp: Path, tmp_path: Path,
                                            sql: str) -> None:
    out = _output(tmp_path / "out")
    with pytest.raises(DataError, match="query refused") as err:
        query(out, sql)
    assert "hidden-value" not in str(err.value) and "\n" not in str(err.value)
    assert sorted(p.name for p in (in_folder_with_tmp / ".tmp").iterdir()) == ["secret.csv"]
    assert (in_folder_with_tmp / ":memory:.wal").read_text() == "wal\n"


def test_the_allow_list_is_empty_and_spill_is_private(tmp_path: Path) -> None:
    con = connect(_output(tmp_path / "out"))
    rows = dict(con.execute("SELECT name, value FROM duckdb_settings() WHERE name IN "
                            "('allowed_directories', 'allowed_paths', 'temp_directory', "
                            "'enable_external_access', 'lock_configuration')").fetchall())
    close(con)
    spill = Path(rows["temp_directory"])
    assert not spill.exists()
    assert spill.name.startswith("m3gd-duckdb-") and spill.parent != Path.cwd(), rows
    assert rows["allowed_directories"] == f"[{spill}/]" and rows["allowed_paths"] == "[]", rows
    assert rows["enable_external_access"] == "false" and rows["lock_configuration"] == "true"


def test_the_tables_stay_readable_in_the_sandbox(in_folder_with_tmp: Path,
                                                 tmp_path: Path) -> None:
    out = _output(tmp_path / "out")
    assert query(out, "SELECT sum(frame) AS s FROM view_stats").to_pylist() == [{"s": 6}]


def interrupt_once_running(monkeypatch: pytest.MonkeyPatch, after_s: float = 0.3
                           ) -> list[float]:
    """Send SIGINT to this process `after_s` after the query starts running (in its worker
    thread); the list gets the time it was sent."""
    import pipeline.analysis.query as q

    sent: list[float] = []
    running = q._consumed

    def interrupt() -> None:
        sent.append(time.monotonic())
        os.kill(os.getpid(), signal.SIGINT)

    def consumed(*args: object) -> object:
        threading.Timer(after_s, interrupt).start()
        return running(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(q, "_consumed", consumed)
    return sent


def test_ctrl_c_stops_a_query_within_a_second(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        python_sigint: None) -> None:
    out = _output(tmp_path / "out")
    sent = interrupt_once_running(monkeypatch)
    with pytest.raises(Interrupted):
        query(out, "SELECT count(*) FROM range(1000000000000) t(i) WHERE i % 7 = 3")
    assert sent and time.monotonic() - sent[0] < 1.0


def test_head_keeps_the_first_rows_and_counts_all(tmp_path: Path) -> None:
    out = _output(tmp_path / "out")
    first = head(out, "SELECT i FROM range(5000) t(i) ORDER BY i", 3)
    assert first.table.column("i").to_pylist() == [0, 1, 2]
    assert (first.total, first.left_out) == (5000, 4997)
    every = head(out, "SELECT i FROM range(7) t(i)", None)
    assert (every.table.num_rows, every.left_out) == (7, 0)


@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_export_writes_every_row_with_our_writer(tmp_path: Path, fmt: str) -> None:
    out = _output(tmp_path / "out")
    path = tmp_path / f"frames.{fmt}"
    n = export(out, "SELECT recording, frame FROM view_stats ORDER BY frame", path, fmt)
    table = pq.read_table(path) if fmt == "parquet" else pacsv.read_csv(path)
    assert n == 3 and table.column("frame").to_pylist() == [0, 1, 5]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_failed_export_leaves_no_file(tmp_path: Path) -> None:
    out = _output(tmp_path / "out")
    path = tmp_path / "x.parquet"
    with pytest.raises(DataError, match="query failed"):
        export(out, "SELECT nope FROM view_stats", path, "parquet")
    assert not path.exists()


def test_duckdb_hint_lines_are_kept_on_one_line(tmp_path: Path) -> None:
    out = _output(tmp_path / "out")
    with pytest.raises(DataError) as err:
        query(out, "SELECT fram FROM view_stats")
    text = str(err.value)
    assert "\n" not in text and 'Candidate bindings: "frame"' in text, text
    assert error_line(ValueError("Parser Error: x\n\nLINE 1: selec 1\n  ^")) == "Parser Error: x"
