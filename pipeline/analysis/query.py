"""SQL over the statistics tables with DuckDB, and canned reports for analysts.

Every Parquet table of the output is a view, by name, when its files exist (`table_files`;
`QUERYABLE` and `INDEX_QUERYABLE`: each table and the command that writes it): `view_stats`,
`cell_stats`, `accuracy` (partitioned by recording), `alignment` (one file), `clips`, and the
recording index tables (`rejects`, `selection`, `images`, ...: one file per recording, the
folder giving the `recording` column). Any Parquet reader can read the same files.

Each table is an Arrow dataset (local files or objects on `s3://bucket/prefix` through
pyarrow's S3 filesystem) registered in DuckDB, which scans it with projection and filter
pushdown and opens no file itself: the connection runs with `enable_external_access = false`
and its configuration locked, so SQL cannot read or write other files, ATTACH databases, or
INSTALL / LOAD extensions; `allow_files=True` (`m3gd stats query --allow-files`) gives SQL
the user's own file access.
"""

from __future__ import annotations

from pathlib import Path

import duckdb
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.fs as pafs

from schemas.errors import DataError
from schemas.layout import CLIPS_FILENAME, INDEX_DIRNAME, STATS_DIRNAME, OutputLayout
from schemas.object_store import (
    StorageError,
    check_location,
    filesystem,
    is_url,
    parse_url,
    reason,
    where,
)
from schemas.tables import INDEX_QUERYABLE, QUERYABLE

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
    """An in-memory DuckDB; without `allow_files`, external access off (no file, network,
    ATTACH or extension) and the configuration locked, once the tables are registered."""
    return duckdb.connect(config={} if allow_files else {"enable_external_access": False})


def _lock(con: duckdb.DuckDBPyConnection, allow_files: bool) -> duckdb.DuckDBPyConnection:
    """`con` with its configuration locked (no SET can lift the sandbox) unless files are
    allowed."""
    if not allow_files:
        con.execute("SET lock_configuration = true")
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


def query(output_dir: Path | str, sql: str, allow_files: bool = False) -> pa.Table:
    """Run `sql` over the output's tables; return an Arrow table. Without `allow_files`,
    SQL that reads or writes files (COPY, read_csv, ATTACH, INSTALL, LOAD, ...) is refused:
    a DataError, one line."""
    con = connect(output_dir, allow_files)
    try:
        return con.sql(sql).to_arrow_table()
    except duckdb.Error as err:
        place = (f"{parse_url(output_dir)}/{STATS_DIRNAME}" if is_url(output_dir)
                 else OutputLayout(Path(output_dir)).stats)
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        if isinstance(err, duckdb.PermissionException) or "configuration has been locked" in first:
            reason_ = first.split(": ", 1)[-1]
            raise DataError(f"query refused: {reason_} "
                            "(`stats query` reads only the output's tables; `--allow-files` "
                            "gives SQL your file access)") from err
        raise DataError(f"query failed over {place}: {first}{_missing_hint(con, err)}") from err
    finally:
        con.close()


def summary(output_dir: Path | str, name: str) -> pa.Table:
    """One canned report by name (see SUMMARIES)."""
    if name not in SUMMARIES:
        raise DataError(f"unknown summary {name!r}; one of {sorted(SUMMARIES)}")
    return query(output_dir, SUMMARIES[name])
