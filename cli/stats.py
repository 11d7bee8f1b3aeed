"""`m3gd stats ...`: SQL and canned reports over the packet statistics (DuckDB over Parquet)."""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer

from cli.common import config_of, console, fail, print_arrow, stdout
from schemas.tables import INDEX_QUERYABLE, QUERYABLE

HELP = "Query packet statistics (DuckDB over Parquet)."
SUMMARY_ROWS = 40


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
          allow_files: Annotated[bool, typer.Option(
              "--allow-files", help="Let the SQL use your file access (read_csv, COPY ... TO, "
              "ATTACH, INSTALL / LOAD). Off by default: only the tables below are "
              "reachable.")] = False) -> None:
    """Run DuckDB SQL over the output's tables.

    By default DuckDB runs with external access off: the SQL reads the tables below and
    nothing else (no other file read or written, no ATTACH, no extensions); `--allow-files`
    lifts this. A table that does not exist is answered with the tables that do."""
    from pipeline.analysis.query import query as run_query  # duckdb: slow to import

    try:
        table = run_query(config_of(ctx).output_dir, sql, allow_files)
    except ValueError as err:
        fail(str(err).splitlines()[0])
    print_arrow(table, as_json)


query.__doc__ = (query.__doc__ or "") + _tables_help()


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
        except ValueError as err:
            if key == "rejects" and "checks" in results:  # ingest ran, stats not yet
                console.print(f"rejects: {str(err).splitlines()[0]}", highlight=False,
                             soft_wrap=True)
                continue
            fail(str(err).splitlines()[0])
    if as_json:
        for line in json_lines(results):
            stdout.out(line, highlight=False)
        return
    for key, table in results.items():
        if key == "checks":
            _print_checks(table)
            continue
        stdout.print(f"[bold]{key}[/]")
        if table.num_rows == 0:
            stdout.print("(no rows)")
            continue
        print_arrow(table.slice(0, SUMMARY_ROWS), False)
        if table.num_rows > SUMMARY_ROWS:
            stdout.print(f"(first {SUMMARY_ROWS} of {table.num_rows} rows; `--json` or "
                         "`m3gd stats query` return all)", highlight=False)


def json_lines(results: dict[str, Any]) -> list[str]:
    """One JSON object per row of every report (Arrow tables, by name), in order, each with
    `summary`: the report's name first (values JSON cannot hold, e.g. dates, as text)."""
    return [json.dumps({"summary": name, **row}, default=str)
            for name, table in results.items() for row in table.to_pylist()]


def _print_checks(checks: Any) -> None:
    """The plausibility checks per recording and topic, and the ones that do not fit."""
    stdout.print("[bold]checks[/] (plausibility checks per recording and topic)")
    print_arrow(checks.drop_columns(["detail"]), False)
    for r in checks.to_pylist():
        if r["state"] in ("off", "capped"):
            stdout.print(f"{r['recording']}: check {r['check']} does not fit topic "
                         f"{r['topic']} ({r['state']}): {r['detail']}",
                         highlight=False, soft_wrap=True)
