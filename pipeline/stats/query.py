"""SQL over the statistics tables with DuckDB, and canned reports for analysts.

Views registered: `view_stats`, `cell_stats`, `accuracy` (hive-partitioned by recording;
`accuracy` is written by `m3gd accuracy`) and `clips`, when their files exist.
Any Parquet reader can read the same files.
"""

from __future__ import annotations

from pathlib import Path

import duckdb
import pyarrow as pa

from schemas.errors import DataError
from schemas.layout import OutputLayout

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


def connect(output_dir: Path) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB connection with views over the output's tables."""
    con = duckdb.connect()
    stats = OutputLayout(output_dir).stats
    for name in ("view_stats", "cell_stats", "accuracy"):
        if any((stats / name).glob("recording=*/*.parquet")):
            pattern = str(stats / name / "*" / "*.parquet")
            con.execute(f"CREATE VIEW {name} AS SELECT * FROM read_parquet("
                        f"'{pattern}', hive_partitioning = false)")
    clips = OutputLayout(output_dir).clips
    if clips.exists():
        con.execute(f"CREATE VIEW clips AS SELECT * FROM read_parquet('{clips}')")
    return con


def query(output_dir: Path, sql: str) -> pa.Table:
    """Run `sql` over the output's tables; return an Arrow table."""
    con = connect(output_dir)
    try:
        return con.sql(sql).to_arrow_table()
    except duckdb.Error as err:
        raise DataError(f"query failed over {OutputLayout(output_dir).stats}: {err}") from err
    finally:
        con.close()


def summary(output_dir: Path, name: str) -> pa.Table:
    """One canned report by name (see SUMMARIES)."""
    if name not in SUMMARIES:
        raise DataError(f"unknown summary {name!r}; one of {sorted(SUMMARIES)}")
    return query(output_dir, SUMMARIES[name])
