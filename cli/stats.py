"""`m3gd stats ...`: SQL and canned reports over the packet statistics (DuckDB over Parquet)."""

from __future__ import annotations

from typing import Annotated

import typer

from cli.common import config_of, fail, print_arrow, stdout

HELP = "Query packet statistics (DuckDB over Parquet)."
SUMMARY_ROWS = 40


def query(ctx: typer.Context, sql: str,
          as_json: Annotated[bool, typer.Option("--json")] = False) -> None:
    """Run SQL over view_stats, cell_stats and clips."""
    from pipeline.analysis.query import query as run_query  # duckdb: slow to import

    try:
        table = run_query(config_of(ctx).output_dir, sql)
    except ValueError as err:
        fail(str(err).splitlines()[0])
    print_arrow(table, as_json)


def summary(ctx: typer.Context, name: Annotated[str | None, typer.Argument(
        help="dtau | occupancy | sparse_views | rejects (default: all)")] = None) -> None:
    """Canned reports: delta-tau per recording and camera, occupancy, sparse views."""
    from pipeline.analysis.query import SUMMARIES, check_table
    from pipeline.analysis.query import summary as run_summary

    out = config_of(ctx).output_dir
    for key in [name] if name else list(SUMMARIES):
        if key == "rejects":  # the checks that reject messages, per topic
            checks = check_table(out)
            if checks is not None:
                stdout.print("[bold]checks[/] (plausibility checks per recording and topic)")
                print_arrow(checks.drop_columns(["detail"]), False)
                for r in checks.to_pylist():
                    if r["state"] in ("off", "capped"):
                        stdout.print(f"{r['recording']}: check {r['check']} does not fit topic "
                                     f"{r['topic']} ({r['state']}): {r['detail']}",
                                     highlight=False, soft_wrap=True)
        try:
            table = run_summary(out, key)
        except ValueError as err:
            fail(str(err))
        stdout.print(f"[bold]{key}[/]")
        if table.num_rows == 0:
            stdout.print("(no rows)")
            continue
        print_arrow(table.slice(0, SUMMARY_ROWS), False)
        if table.num_rows > SUMMARY_ROWS:
            stdout.print(f"(first {SUMMARY_ROWS} of {table.num_rows} rows; "
                         "`m3gd stats query` returns all)", highlight=False)
