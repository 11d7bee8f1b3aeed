"""SQL over the statistics tables with DuckDB, and canned reports for analysts.

Views registered, when their files exist (`QUERYABLE`: each table and the command that writes
it): `view_stats`, `cell_stats` (hive-partitioned by recording), `clips`, `accuracy`
(partitioned by recording, written by `m3gd accuracy`) and `alignment` (one file, written by
`m3gd align`).
Any Parquet reader can read the same files.

An output on `s3://bucket/prefix` is queried through Arrow datasets on pyarrow's S3
filesystem, registered in DuckDB (which scans them with projection and filter pushdown;
DuckDB's own httpfs extension is not needed).
"""

from __future__ import annotations

from pathlib import Path

import duckdb
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.fs as pafs

from schemas.errors import DataError
from schemas.layout import CLIPS_FILENAME, STATS_DIRNAME, OutputLayout
from schemas.object_store import (
    StorageError,
    check_location,
    filesystem,
    is_url,
    parse_url,
    reason,
    where,
)
from schemas.tables import QUERYABLE

TABLES = ("view_stats", "cell_stats", "accuracy")
"""Tables partitioned by recording under stats/<table>/recording=<rec>/."""
ALIGNMENT_KEY = f"{STATS_DIRNAME}/alignment.parquet"
"""The alignment table: one file (pipeline.analysis.align.ALIGNMENT_FILE)."""


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


def connect_remote(location: str | Path) -> duckdb.DuckDBPyConnection:
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
    stats = url.key(STATS_DIRNAME)
    con = duckdb.connect()
    for name in TABLES:
        parts = sorted(k for k in keys if k.startswith(f"{stats}/{name}/recording=")
                       and k.endswith(".parquet"))
        if parts:
            con.register(name, pads.dataset(parts, filesystem=fs, format="parquet"))
    if url.key(CLIPS_FILENAME) in keys:
        con.register("clips", pads.dataset(url.key(CLIPS_FILENAME), filesystem=fs,
                                           format="parquet"))
    if url.key(ALIGNMENT_KEY) in keys:
        con.register("alignment", pads.dataset(url.key(ALIGNMENT_KEY), filesystem=fs,
                                               format="parquet"))
    return con


def connect(output_dir: Path | str) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB connection with views over the output's tables (a local
    directory or an `s3://` URL)."""
    if is_url(output_dir):
        return connect_remote(output_dir)
    output_dir = Path(output_dir)
    con = duckdb.connect()
    stats = OutputLayout(output_dir).stats
    for name in TABLES:
        if any((stats / name).glob("recording=*/*.parquet")):
            pattern = str(stats / name / "*" / "*.parquet")
            con.execute(f"CREATE VIEW {name} AS SELECT * FROM read_parquet("
                        f"'{pattern}', hive_partitioning = false)")
    clips = OutputLayout(output_dir).clips
    if clips.exists():
        con.execute(f"CREATE VIEW clips AS SELECT * FROM read_parquet('{clips}')")
    alignment = output_dir / ALIGNMENT_KEY
    if alignment.exists():
        con.execute(f"CREATE VIEW alignment AS SELECT * FROM read_parquet('{alignment}')")
    return con


def _missing_hint(con: duckdb.DuckDBPyConnection, err: duckdb.Error) -> str:
    """For a query naming a known table that this output does not hold yet: which command
    writes it."""
    if not isinstance(err, duckdb.CatalogException):
        return ""
    present = {row[0] for row in con.execute("SELECT view_name FROM duckdb_views()").fetchall()}
    present |= {row[0] for row in con.execute("SELECT table_name FROM duckdb_tables()")
                .fetchall()}
    for name, text in QUERYABLE.items():
        if name not in present and name in str(err):
            return f" (table {name} is written by {text.rsplit('; ', 1)[1]}: run it first)"
    return ""


def query(output_dir: Path | str, sql: str) -> pa.Table:
    """Run `sql` over the output's tables; return an Arrow table."""
    con = connect(output_dir)
    try:
        return con.sql(sql).to_arrow_table()
    except duckdb.Error as err:
        place = (f"{parse_url(output_dir)}/{STATS_DIRNAME}" if is_url(output_dir)
                 else OutputLayout(Path(output_dir)).stats)
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise DataError(f"query failed over {place}: {first}{_missing_hint(con, err)}") from err
    finally:
        con.close()


def summary(output_dir: Path | str, name: str) -> pa.Table:
    """One canned report by name (see SUMMARIES)."""
    if name not in SUMMARIES:
        raise DataError(f"unknown summary {name!r}; one of {sorted(SUMMARIES)}")
    return query(output_dir, SUMMARIES[name])
