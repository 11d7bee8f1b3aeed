"""SQL over the statistics tables with DuckDB, and canned reports for analysts.

Every Parquet table of the output is a view, by name, when its files exist (`table_files`;
`QUERYABLE` and `INDEX_QUERYABLE`: each table and the command that writes it): `view_stats`,
`cell_stats`, `accuracy` (partitioned by recording), `alignment` (one file), `clips`, and the
recording index tables (`rejects`, `selection`, `images`, ...: one file per recording, the
folder giving the `recording` column). Any Parquet reader can read the same files.

Each table is an Arrow dataset (local files or objects on `s3://bucket/prefix` through
pyarrow's S3 filesystem) registered in DuckDB, which scans it with projection and filter
pushdown and opens no file itself: the connection runs with `enable_external_access = false`,
an empty allow-list (DuckDB would otherwise keep `<cwd>/.tmp/` and `<cwd>/:memory:.wal` on it:
its default spill folder and the WAL of an in-memory database), a private spill folder of its
own (removed with the connection) and its configuration locked, so SQL cannot read or write
other files, ATTACH databases, or INSTALL / LOAD extensions; `allow_files=True`
(`m3gd stats query --allow-files`) gives SQL the user's own file access.

A query runs in a worker thread: Ctrl-C (KeyboardInterrupt in the main thread) interrupts it
through DuckDB's `interrupt()` and is raised again once it stopped. Results are read as a
stream of Arrow batches: `head` keeps the first rows and counts the rest, `export` writes
every row to a Parquet or CSV file (our writer, atomically; SQL itself writes no file).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, TypeVar

import duckdb
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.fs as pafs

from schemas.atomic_io import write_atomic
from schemas.errors import DataError
from schemas.layout import CLIPS_FILENAME, INDEX_DIRNAME, STATS_DIRNAME, OutputLayout
from schemas.tables import INDEX_QUERYABLE, QUERYABLE
from store.object_store import (
    StorageError,
    check_location,
    filesystem,
    is_url,
    parse_url,
    reason,
    where,
)

SUMMARIES: dict[str, str] = {
    # Δτ figures of accepted views only; rejected views (beyond the bound, odometry gaps) apart
    "dtau": """
        SELECT recording, camera, count(*) AS views,
               count(*) FILTER (WHERE reject_reason IS NOT NULL) AS rejected,
               round(avg(dtau_s) FILTER (WHERE reject_reason IS NULL) * 1e3, 3) AS mean_dtau_ms,
               round(quantile_cont(abs(dtau_s), 0.5) FILTER (WHERE reject_reason IS NULL) * 1e3,
                     3) AS median_abs_dtau_ms,
               round(quantile_cont(abs(dtau_s), 0.95) FILTER (WHERE reject_reason IS NULL) * 1e3,
                     3) AS p95_abs_dtau_ms,
               round(max(abs(dtau_s)) FILTER (WHERE reject_reason IS NULL) * 1e3, 3)
                   AS max_abs_dtau_ms,
               round(max(abs(dtau_s)) FILTER (WHERE reject_reason IS NOT NULL) * 1e3, 3)
                   AS max_abs_dtau_rejected_ms
        FROM view_stats GROUP BY recording, camera ORDER BY recording, camera""",
    "occupancy": """
        SELECT c.row, c.col, count(*) AS views_supported,
               round(count(*) / (SELECT count(*) FROM view_stats
                                 WHERE reject_reason IS NULL), 4) AS fraction,
               round(avg(c.n), 2) AS mean_points, round(avg(c.depth_mean_m), 2) AS mean_depth_m
        FROM cell_stats c GROUP BY c.row, c.col ORDER BY c.row, c.col""",
    "sparse_views": """
        SELECT recording, camera, frame, stamp_ns, supported_cells, points_in_frustum
        FROM view_stats WHERE reject_reason IS NULL AND supported_cells < 3
        ORDER BY recording, camera, frame""",
    "rejects": """
        SELECT recording, camera, reject_reason, count(*) AS views
        FROM view_stats WHERE reject_reason IS NOT NULL
        GROUP BY recording, camera, reject_reason ORDER BY recording, camera, reject_reason""",
}


def check_table(output_dir: Path | str) -> pa.Table | None:
    """The plausibility checks of every recording (`index/<recording>/checks.parquet`): topic,
    check, state, messages judged, flagged and rejected; None when no local index has one."""
    if is_url(output_dir):
        return None
    from schemas.recording_index import CHECKS, read_index_table

    files = sorted(OutputLayout(Path(output_dir)).index.glob("*/checks.parquet"))
    parts = []
    for f in files:
        t = read_index_table(f, CHECKS)
        parts.append(t.add_column(0, "recording", pa.array([f.parent.name] * t.num_rows,
                                                          pa.string())))  # fmt: skip
    return pa.concat_tables(parts).replace_schema_metadata(None) if parts else None


def table_files(keys: list[str], root: str) -> dict[str, tuple[list[str], bool]]:
    """The Parquet tables among the files `keys` (paths under `root`, '/'-separated): name ->
    (its files, whether the recording comes from the folder). Tables are the statistics
    (`stats/<name>/<rec>.parquet`, and `stats/<name>.parquet`), the clip index
    (`clips.parquet`) and the recording index (`index/<rec>/<name>.parquet`: `rejects`,
    `selection`, `images`, ...; the folder is the `recording` column). Intermediate parts,
    temp and hidden files are not tables."""
    found: dict[str, tuple[list[str], bool]] = {}
    for key in sorted(keys):
        rel = key[len(root):].lstrip("/").split("/") if key.startswith(root) else []
        if not rel or not rel[-1].endswith(".parquet") or rel[-1].startswith("."):
            continue
        stem = rel[-1].removesuffix(".parquet")
        if rel == [CLIPS_FILENAME]:
            name, by_folder = "clips", False
        elif len(rel) == 2 and rel[0] == STATS_DIRNAME:
            name, by_folder = stem, False
        elif len(rel) == 3 and rel[0] == STATS_DIRNAME:  # <table>/<recording>.parquet
            name, by_folder = rel[1], False
        elif len(rel) == 4 and rel[0] == STATS_DIRNAME and rel[2].startswith("recording="):
            name, by_folder = rel[1], False  # layout version 1, until the stats stage reruns
        elif len(rel) == 3 and rel[0] == INDEX_DIRNAME:
            name, by_folder = stem, True
        else:
            continue
        found.setdefault(name, ([], by_folder))[0].append(key)
    return found


def _register(con: duckdb.DuckDBPyConnection, tables: dict[str, tuple[list[str], bool]],
              fs: pafs.FileSystem, index_root: str) -> None:
    """Each table as an Arrow dataset of its files (scanned by DuckDB with projection and
    filter pushdown; DuckDB itself opens no file)."""
    by_folder = pads.partitioning(pa.schema([("recording", pa.string())]))
    for name, (files, from_folder) in tables.items():
        con.register(name, pads.dataset(files, filesystem=fs, format="parquet",
                                        partitioning=by_folder if from_folder else None,
                                        partition_base_dir=index_root if from_folder else None))


def _open(allow_files: bool) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB without progress bar; without `allow_files`, sandboxed
    (`_sandbox`) once the tables are registered (`_lock`)."""
    con = duckdb.connect()
    con.execute("SET enable_progress_bar = false")
    return con


def _sandbox(con: duckdb.DuckDBPyConnection) -> None:
    """Close `con` to every file: spill into a private folder of its own (made here, empty,
    removed by `close`: the one folder DuckDB keeps on its allow-list), nothing else on the
    allow-list (not DuckDB's defaults `<cwd>/.tmp/` and
    `<cwd>/:memory:.wal`), external access off, configuration locked."""
    spill = tempfile.mkdtemp(prefix="m3gd-duckdb-")
    _SPILL[id(con)] = spill
    for statement in ("SET temp_directory = '{}'".format(spill.replace("'", "''")),
                      "SET allowed_directories = []",
                      "SET allowed_paths = []",
                      "SET enable_external_access = false",
                      "SET lock_configuration = true"):
        con.execute(statement)


_SPILL: dict[int, str] = {}
"""The private spill folder of each sandboxed connection (by id), removed by `close`."""


def close(con: duckdb.DuckDBPyConnection) -> None:
    """Close `con` and remove its private spill folder, if it has one. A connection still
    busy (a query that did not stop within its grace after an interrupt) is left to the
    process's exit."""
    with contextlib.suppress(duckdb.Error):
        con.close()
    spill = _SPILL.pop(id(con), None)
    if spill is not None:
        shutil.rmtree(spill, ignore_errors=True)


def _lock(con: duckdb.DuckDBPyConnection, allow_files: bool) -> duckdb.DuckDBPyConnection:
    """`con` sandboxed (`_sandbox`: no SET can lift it) unless files are allowed."""
    if not allow_files:
        _sandbox(con)
    return con


def connect_remote(location: str | Path, allow_files: bool = False
                   ) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB connection over the tables of an output on `s3://…`: each table
    an Arrow dataset of its Parquet objects (listed once)."""
    url = parse_url(location)
    fs = filesystem()
    check_location(fs, url)
    try:
        found = fs.get_file_info(pafs.FileSelector(url.key(""), recursive=True,
                                                   allow_not_found=True))
    except OSError as err:
        raise StorageError(f"{where(url)}: {reason(err)}") from err
    keys = [f.path for f in found if f.type == pafs.FileType.File]
    con = _open(allow_files)
    root = url.key("").rstrip("/")
    _register(con, table_files(keys, root), fs, url.key(INDEX_DIRNAME))
    return _lock(con, allow_files)


def connect(output_dir: Path | str, allow_files: bool = False) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB connection with a view per Parquet table of the output (a local
    directory or an `s3://` URL; `table_files`). Without `allow_files` the SQL reaches
    nothing else: no file read or written, no ATTACH, INSTALL or LOAD."""
    if is_url(output_dir):
        return connect_remote(output_dir, allow_files)
    layout = OutputLayout(Path(output_dir))
    root = layout.root.resolve()
    keys = [p.as_posix() for base in (layout.stats, layout.index) if base.exists()
            for p in base.resolve().rglob("*.parquet")]
    if layout.clips.exists():
        keys.append(layout.clips.resolve().as_posix())
    con = _open(allow_files)
    _register(con, table_files(keys, root.as_posix()), pafs.LocalFileSystem(),
              (root / INDEX_DIRNAME).as_posix())
    return _lock(con, allow_files)


def tables_of(con: duckdb.DuckDBPyConnection) -> list[str]:
    """The names of the tables and views a connection holds (the user's own included)."""
    rows = con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal UNION "
                       "SELECT table_name FROM duckdb_tables()").fetchall()
    return sorted(str(r[0]) for r in rows)


def _missing_hint(con: duckdb.DuckDBPyConnection, err: duckdb.Error) -> str:
    """For a query naming a table this output does not hold: the tables it holds, and for a
    known table not written yet, the command that writes it."""
    if not isinstance(err, duckdb.CatalogException) or "does not exist" not in str(err):
        return ""
    present = tables_of(con)
    for name, text in {**QUERYABLE, **INDEX_QUERYABLE}.items():
        if name not in present and name in str(err):
            return (f" (table {name} is written by {text.rsplit('; ', 1)[1]}: run it first;"
                    f" tables here: {', '.join(present) or 'none'})")
    return f" (tables here: {', '.join(present) or 'none'})"


T = TypeVar("T")


class Interrupted(KeyboardInterrupt):
    """A query stopped by Ctrl-C (DuckDB's `interrupt()`), once it stopped."""


@dataclass(frozen=True)
class Head:
    """The first rows of a query's result, and how many rows it had in all."""

    table: pa.Table
    total: int

    @property
    def left_out(self) -> int:
        """Rows of the result not in `table`."""
        return int(self.total - self.table.num_rows)


def _interruptible(con: duckdb.DuckDBPyConnection, work: Callable[[], T]) -> T:
    """`work()` (DuckDB calls on `con`) in a worker thread; Ctrl-C in the main thread
    interrupts the query (`con.interrupt()`) and raises `Interrupted` once it stopped
    (DuckDB, busy in C++, would not see the signal before it finished)."""
    box: dict[str, object] = {}
    done = threading.Event()  # not Thread.join: one that Ctrl-C broke may return early

    def run() -> None:
        try:
            box["value"] = work()
        except BaseException as err:  # handed to the main thread
            box["error"] = err
        finally:
            done.set()

    threading.Thread(target=run, name="m3gd-query", daemon=True).start()
    try:
        while not done.wait(0.05):
            pass
    except KeyboardInterrupt:
        con.interrupt()
        done.wait(5.0)
        raise Interrupted("query interrupted") from None
    if "error" in box:
        raise box["error"]  # type: ignore[misc]
    return box["value"]  # type: ignore[return-value]


HINTS = ("Candidate bindings:", "Did you mean")
"""DuckDB's hint lines kept in a one-line error (the rest: positions, function lists)."""


def error_line(err: Exception) -> str:
    """DuckDB's error as one line: its first line and its hint lines (`HINTS`)."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    if not lines:
        return type(err).__name__
    return "; ".join([lines[0], *(line for line in lines[1:] if line.startswith(HINTS))])


def _refusal(output_dir: Path | str, con: duckdb.DuckDBPyConnection,
             err: duckdb.Error) -> DataError:
    """The one-line DataError for a failed query: refused by the sandbox, or failed (with
    DuckDB's hints and the tables this output holds)."""
    place = (f"{parse_url(output_dir)}/{STATS_DIRNAME}" if is_url(output_dir)
             else OutputLayout(Path(output_dir)).stats)
    first = error_line(err)
    if isinstance(err, duckdb.PermissionException) or "configuration has been locked" in first:
        reason_ = first.split(": ", 1)[-1]
        return DataError(f"query refused: {reason_} (`stats query` reads only the output's "
                         "tables; `--allow-files` gives SQL your file access)")
    return DataError(f"query failed over {place}: {first}{_missing_hint(con, err)}")


def _over(output_dir: Path | str, sql: str, allow_files: bool,
          consume: Callable[[pa.RecordBatchReader | None], T]) -> T:
    """`consume` the stream of `sql`'s result over the output's tables (see `query`)."""
    con = connect(output_dir, allow_files)
    try:
        return _interruptible(con, lambda: _consumed(con, sql, consume))
    except duckdb.Error as err:
        raise _refusal(output_dir, con, err) from err
    finally:
        close(con)


def _consumed(con: duckdb.DuckDBPyConnection, sql: str,
              consume: Callable[[pa.RecordBatchReader | None], T]) -> T:
    """`consume` the result stream of `sql`, closing it after (an open stream keeps the
    connection busy, even one that an error or an interrupt ended)."""
    reader = _reader(con.sql(sql))
    try:
        return consume(reader)
    finally:
        if reader is not None:
            reader.close()


def _reader(relation: duckdb.DuckDBPyRelation | None) -> pa.RecordBatchReader | None:
    """The result of a statement as a stream of Arrow batches; None for one without a
    result (SET)."""
    return None if relation is None else relation.to_arrow_reader()


def query(output_dir: Path | str, sql: str, allow_files: bool = False) -> pa.Table:
    """Run `sql` over the output's tables; return an Arrow table. Without `allow_files`,
    SQL that reads or writes files (COPY, read_csv, ATTACH, INSTALL, LOAD, ...) is refused:
    a DataError, one line. Ctrl-C stops it (`Interrupted`)."""
    return _over(output_dir, sql, allow_files, _all_rows)


def _all_rows(reader: pa.RecordBatchReader | None) -> pa.Table:
    """Every row of `reader` (an empty table for a statement without a result)."""
    return pa.table({}) if reader is None else reader.read_all()


def head(output_dir: Path | str, sql: str, limit: int | None,
         allow_files: bool = False) -> Head:
    """The first `limit` rows of `sql`'s result (all when None) and its row count; the
    other rows are counted as they stream, not kept."""

    def keep(reader: pa.RecordBatchReader | None) -> Head:
        if reader is None:
            return Head(pa.table({}), 0)
        batches, kept, total = [], 0, 0
        for batch in reader:
            total += batch.num_rows
            if limit is None or kept < limit:
                part = batch if limit is None else batch.slice(0, limit - kept)
                batches.append(part)
                kept += part.num_rows
        return Head(pa.Table.from_batches(batches, schema=reader.schema), total)

    return _over(output_dir, sql, allow_files, keep)


EXPORT_FORMATS = ("parquet", "csv")
"""The formats `export` writes."""


def export(output_dir: Path | str, sql: str, path: Path, fmt: str,
           allow_files: bool = False) -> int:
    """Write every row of `sql`'s result to `path` as `fmt` (`EXPORT_FORMATS`) and return the
    row count. Our writer writes it (SQL itself writes no file): into a temporary beside
    `path`, flushed to disk, renamed over it; an error or Ctrl-C leaves no partial file."""
    if fmt not in EXPORT_FORMATS:
        raise DataError(f"unknown format {fmt!r}; one of {', '.join(EXPORT_FORMATS)}")

    def write_all(reader: pa.RecordBatchReader | None) -> int:
        if reader is None:
            raise DataError("the statement returns no rows to export (a SELECT does)")
        return _write_stream(reader, path, fmt)

    return _over(output_dir, sql, allow_files, write_all)


def _write_stream(reader: pa.RecordBatchReader, path: Path, fmt: str) -> int:
    """Write the batches of `reader` to `path` as `fmt`, atomically; the row count."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    rows = [0]

    def write(f: BinaryIO) -> None:
        writer = (pq.ParquetWriter(f, reader.schema) if fmt == "parquet"
                  else pacsv.CSVWriter(f, reader.schema))
        with writer:
            for batch in reader:
                writer.write_batch(batch)
                rows[0] += batch.num_rows
        f.flush()
        os.fsync(f.fileno())

    write_atomic(path, write)
    return rows[0]


def summary(output_dir: Path | str, name: str) -> pa.Table:
    """One canned report by name (see SUMMARIES)."""
    if name not in SUMMARIES:
        raise DataError(f"unknown summary {name!r}; one of {sorted(SUMMARIES)}")
    return query(output_dir, SUMMARIES[name])
