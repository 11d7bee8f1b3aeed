"""`m3gd stats ...`: SQL and canned reports over the packet statistics (DuckDB over Parquet)."""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer

from cli.common import (
    config_of,
    console,
    fail,
    print_arrow,
    refuse_duplicate_columns,
    refuse_foreign_output,
    stdout,
    styled,
)
from schemas.tables import INDEX_QUERYABLE, QUERYABLE
from store.object_store import is_url

HELP = "Query packet statistics (DuckDB over Parquet)."
SUMMARY_ROWS = 40
QUERY_ROWS = 1000
"""Rows `stats query` prints unless `--limit` says otherwise."""


def _tables_help() -> str:
    """The tables `stats query` reads, one paragraph each (click keeps \\b blocks as is)."""
    lines = [f"  {name}: {text}" for name, text in QUERYABLE.items()]
    index = [f"  {name}: {text}" for name, text in INDEX_QUERYABLE.items()]
    return ("\n\n\b\nTables (each with the command that writes it):\n" + "\n".join(lines)
            + "\n\n\b\nIndex tables (a `recording` column, one file per recording):\n"
            + "\n".join(index))


def query(ctx: typer.Context, sql: str,
          as_json: Annotated[bool, typer.Option(
              "--json", help="One JSON object per row.")] = False,
          limit: Annotated[int, typer.Option(
              "--limit", min=0, help="Rows printed at most (0: all); the count of the rest "
              "is said on stderr. `--out` writes all.")] = QUERY_ROWS,
          out: Annotated[Path | None, typer.Option(
              "--out", help="Write every row to this file instead (Parquet, or CSV for a "
              "`.csv` name or `--format csv`).")] = None,
          fmt: Annotated[str | None, typer.Option(
              "--format", help="parquet | csv: the format of `--out`.")] = None,
          allow_files: Annotated[bool, typer.Option(
              "--allow-files", help="Let the SQL use your file access (read_csv, COPY ... TO, "
              "ATTACH, INSTALL / LOAD). Off by default: only the tables below are "
              "reachable.")] = False) -> None:
    """Run DuckDB SQL over the output's tables.

    By default DuckDB runs with external access off: the SQL reads the tables below and
    nothing else (no other file read or written, no ATTACH, no extensions); `--allow-files`
    lifts this. A table that does not exist is answered with the tables that do. Ctrl-C
    stops a running query (exit 130)."""
    from pipeline.analysis.query import head  # duckdb: slow to import

    output_dir = config_of(ctx).output_dir
    if out is not None:
        _export(ctx, sql, out, fmt, allow_files)
        return
    if fmt is not None:
        fail("--format: the format of --out; give --out FILE", 2)
    with _query_errors():
        result = head(output_dir, sql, limit or None, allow_files)
    print_arrow(result.table, as_json)
    if result.left_out:
        console.print(f"({result.left_out} more rows of {result.total} not printed: "
                      "--limit 0 prints all, --out FILE writes all)", soft_wrap=True)


query.__doc__ = (query.__doc__ or "") + _tables_help()


def export(ctx: typer.Context, table: Annotated[str, typer.Argument(
        help="A table of the output (see `m3gd stats query --help`).")],
           out: Annotated[Path, typer.Option("--out", help="The file to write.")],
           fmt: Annotated[str | None, typer.Option(
               "--format", help="parquet | csv (default: from the name of --out, else "
               "parquet).")] = None) -> None:
    """Write one table of the output to a Parquet or CSV file, every row.

    The file is written whole or not at all (a temporary renamed over it); never inside
    the cache store or the output's table folders, never over a file m3gd did not write."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", table):
        fail(f"{table!r}: not a table name (letters, digits, _)", 2)
    _export(ctx, f'SELECT * FROM "{table}"', out, fmt, False)


def _export(ctx: typer.Context, sql: str, out: Path, fmt: str | None,
            allow_files: bool) -> None:
    """Write every row of `sql` to `out` (see `export`); one line naming the file."""
    from pipeline.analysis.query import EXPORT_FORMATS
    from pipeline.analysis.query import export as run_export

    cfg = config_of(ctx)
    fmt = fmt or ("csv" if out.suffix.lower() == ".csv" else "parquet")
    if fmt not in EXPORT_FORMATS:
        fail(f"--format {fmt}: one of {', '.join(EXPORT_FORMATS)}", 2)
    refuse_export_path(out, cfg)
    with _query_errors():
        rows = run_export(cfg.output_dir, sql, out, fmt, allow_files)
    stdout.print(f"{out}: {rows} rows ({fmt})", soft_wrap=True)


def refuse_export_path(path: Path, cfg: Any) -> None:
    """Exit 2 with one line when an export may not be written to `path`: inside the cache
    store, inside the output's table folders (it would read as a table), or over an
    existing file that is not an earlier export (a Parquet or CSV file)."""
    from schemas.layout import OutputLayout

    if not is_url(cfg.output_dir):
        layout = OutputLayout(Path(cfg.output_dir))
        target = path.resolve()
        for folder in (layout.stats, layout.index):
            if folder.resolve() == target.parent or folder.resolve() in target.parents:
                fail(f"{path}: inside the output's tables ({folder}); write the export "
                     "elsewhere", 2)
    refuse_foreign_output(path, cfg, "export", _export_file)


def _export_file(path: Path) -> bool:
    """Whether `path` is a file an export may replace: a Parquet file (its magic) or a CSV
    file by name."""
    if not path.is_file():
        return False
    if path.suffix.lower() == ".csv":
        return True
    with path.open("rb") as f:
        return f.read(4) == b"PAR1"


@contextmanager
def _query_errors() -> Iterator[None]:
    """Exit 1 with the one-line error of a failed query; exit 130 with one line on Ctrl-C."""
    try:
        yield
    except KeyboardInterrupt:
        fail("interrupted: the query stopped", 130)
    except (ValueError, OSError) as err:
        fail(str(err).splitlines()[0] if str(err) else type(err).__name__)


def summary(ctx: typer.Context, name: Annotated[str | None, typer.Argument(
        help="dtau | occupancy | sparse_views | rejects (default: all)")] = None,
            as_json: Annotated[bool, typer.Option(
                "--json", help="JSON Lines: one object per row (all rows), its report's "
                "name in the field `summary`.")] = False) -> None:
    """Canned reports: delta-tau per recording and camera, occupancy, sparse views, rejects
    (with the plausibility checks per recording and topic)."""
    from pipeline.analysis.query import SUMMARIES, check_table
    from pipeline.analysis.query import summary as run_summary

    out = config_of(ctx).output_dir
    results = {}
    for key in [name] if name else list(SUMMARIES):
        if key == "rejects":  # the checks that reject messages, per topic
            checks = check_table(out)
            if checks is not None:
                results["checks"] = checks
        try:
            results[key] = run_summary(out, key)
        except KeyboardInterrupt:
            fail("interrupted: the query stopped", 130)
        except ValueError as err:
            if key == "rejects" and "checks" in results:  # ingest ran, stats not yet
                console.print(f"rejects: {str(err).splitlines()[0]}", soft_wrap=True)
                continue
            fail(str(err).splitlines()[0])
    if as_json:
        for line in json_lines(results):
            sys.stdout.write(line + "\n")
        return
    for key, table in results.items():
        if key == "checks":
            _print_checks(table)
            continue
        stdout.print(styled((key, "bold")))
        if table.num_rows == 0:
            stdout.print("(no rows)")
            continue
        print_arrow(table.slice(0, SUMMARY_ROWS), False)
        if table.num_rows > SUMMARY_ROWS:
            stdout.print(f"(first {SUMMARY_ROWS} of {table.num_rows} rows; `--json` or "
                         "`m3gd stats query` return all)", highlight=False)


def json_lines(results: dict[str, Any]) -> list[str]:
    """One JSON object per row of every report (Arrow tables, by name), in order, each with
    `summary`: the report's name first (values JSON cannot hold, e.g. dates, as text); a
    report with two columns of one name (or one named `summary`) is refused in one line."""
    for table in results.values():
        refuse_duplicate_columns(["summary", *table.column_names])
    return [json.dumps({"summary": name, **row}, default=str)
            for name, table in results.items() for row in table.to_pylist()]


def _print_checks(checks: Any) -> None:
    """The plausibility checks per recording and topic, and the ones that do not fit."""
    stdout.print(styled(("checks", "bold"), " (plausibility checks per recording and topic)"))
    print_arrow(checks.drop_columns(["detail"]), False)
    for r in checks.to_pylist():
        if r["state"] in ("off", "capped"):
            stdout.print(f"{r['recording']}: check {r['check']} does not fit topic "
                         f"{r['topic']} ({r['state']}): {r['detail']}",
                         highlight=False, soft_wrap=True)
