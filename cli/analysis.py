"""Analysis commands of the `m3gd` CLI: `plot`, `accuracy` and `align` (and
`align --consistency`)."""

from __future__ import annotations

from typing import Annotated, Any

import typer
from rich.table import Table

from cli.common import (
    config_of,
    console,
    fail,
    local_output,
    print_arrow,
    stdout,
    styled,
    write_failed,
    write_json,
)


def plot(ctx: typer.Context) -> None:
    """Write the analyst plots (PNG) of the output directory."""
    from pipeline.analysis.figures import make_plots, make_plots_on_store  # matplotlib: slow
    from store.object_store import StorageError, is_url

    out = config_of(ctx).output_dir
    if is_url(out):  # statistics plots drawn from pulled tables, uploaded below plots/
        try:
            urls = make_plots_on_store(out, config_of(ctx).select.max_abs_dt_s)
        except (StorageError, ValueError, FileNotFoundError) as err:
            fail(str(err).splitlines()[0])
        for url in urls:
            stdout.print(url, highlight=False)
        stdout.print("(latent PCA views read cache chunks: drawn on a local output only)")
        return
    if not out.is_dir():
        fail(f"{out}: no output directory; run the pipeline first (m3gd run)")
    try:
        paths = make_plots(out, config_of(ctx).select.max_abs_dt_s)
    except OSError as err:  # a full disk, a read-only folder
        write_failed(err, "plots were")
    for path in paths:
        stdout.print(str(path), highlight=False)
    if not paths:
        stdout.print(f"nothing to plot under {out} yet (no statistics, cache or benchmarks)")


def accuracy(ctx: typer.Context, as_json: Annotated[bool, typer.Option(
        "--json", help="Print the raw summary (accuracy_summary.json) instead of tables.")
        ] = False) -> None:
    """Packet depth against the recordings' ground truth: stats/accuracy, a summary, plots.

    Prints the overall figures and one small table per grouping (|Δτ|, speed, yaw rate),
    then the files written."""
    from pipeline.analysis.accuracy import run_accuracy  # zarr, matplotlib: slow to import
    from pipeline.run.progress import make_progress

    local_output(config_of(ctx).output_dir, "accuracy")
    try:
        with make_progress(console=console, transient=True) as bar:
            task = bar.add_task("accuracy views")  # total unknown until the views are read
            rep = run_accuracy(config_of(ctx), on_view=lambda n: bar.advance(task, n))
    except (ValueError, FileNotFoundError, KeyError) as err:
        fail(str(err).splitlines()[0])
    except OSError as err:  # a full disk, a read-only folder
        write_failed(err, "accuracy tables, summary and plots were")
    if as_json:
        write_json(rep.summary)
    else:
        print_accuracy(rep.summary)
    for path in [*rep.tables, rep.summary_path, *rep.plots]:
        stdout.print(str(path), highlight=False)


ACCURACY_SETTINGS = ("select_time_offset_s", "front_surface", "front_margin_m",
                     "front_margin_rel")
"""Keys of the accuracy summary that are the run's settings, not results
(`pipeline.analysis.accuracy.run_accuracy` writes them beside the figures)."""


def print_accuracy(summary: dict[str, Any]) -> None:
    """The accuracy summary as tables: the results, the settings they were made with
    apart, then each grouping's bins (numbers right-aligned)."""
    from pipeline.analysis.report.accuracy_tables import groupings, overall

    pairs = overall(summary)
    stdout.print(styled(("accuracy", "bold"), " (packet cell depth against ground truth)"))
    stdout.print(_figures([(k, v) for k, v in pairs if k not in ACCURACY_SETTINGS]))
    settings = [(k, v) for k, v in pairs if k in ACCURACY_SETTINGS]
    if settings:
        stdout.print(styled(("settings", "bold"), " (the configuration these results used)"))
        stdout.print(_figures(settings, "setting"))
    for group in groupings(summary):
        stdout.print(styled((group.title, "bold")))
        print_arrow(group.table, False)
        if group.empty_bins:
            stdout.print(f"(no cell in bin {', '.join(group.empty_bins)})", highlight=False)


def _figures(pairs: list[tuple[str, object]], name: str = "figure") -> Table:
    """(name, value) pairs as a two-column table, the values right-aligned."""
    table = Table()
    table.add_column(name)
    table.add_column("value", justify="right")
    for key, value in pairs:
        table.add_row(key, _figure(value))
    return table


def _figure(value: object) -> str:
    """A summary value as text: floats to 4 significant digits."""
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def align(
    ctx: typer.Context,
    pair: Annotated[list[str] | None, typer.Option(
        help="Feature pair A:B, e.g. latents_l0:h (repeatable).")] = None,
    min_cells: int = 3, n_perm: int = 20, seed: int = 0,
    max_images: Annotated[int | None, typer.Option(help="Images per pair (all).")] = None,
    consistency: Annotated[bool, typer.Option(
        "--consistency", help="Instead: reprojection consistency per camera (the clock offset "
        "that makes its views agree on the LiDAR points, the extrinsic rotation that lines "
        "LiDAR edges up with image edges).")] = False,
    max_offset_ms: Annotated[float, typer.Option(
        help="--consistency: clock offsets swept within +- this.")] = 60.0,
    max_rotation_deg: Annotated[float, typer.Option(
        help="--consistency: rotations swept within +- this per axis.")] = 1.0,
    max_pairs: Annotated[int, typer.Option(
        help="--consistency: view pairs per camera (clock offset).")] = 24,
    max_views: Annotated[int, typer.Option(
        help="--consistency: views per camera for the LiDAR edge alignment (rotation; more: "
        "more precise, slower).")] = 64,
    as_json: Annotated[bool, typer.Option("--json", help="--consistency: rows as JSON.")] = False,
) -> None:
    """2D-3D alignment diagnostics over the cache, each beside a permutation null; with
    --consistency, the reprojection-consistency check of every camera's geometry."""
    if consistency:
        _consistency(ctx, max_offset_ms, max_rotation_deg, max_pairs, max_views, as_json)
        return
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn

    from pipeline.analysis.align import (  # zarr, scipy: slow to import
        count_views,
        run_alignment,
        write_alignment,
    )
    from pipeline.run.progress import make_progress

    pairs = [tuple(p.split(":", 1)) for p in (pair or ["latents_l0:h"])]
    if any(len(p) != 2 for p in pairs):
        fail(f"--pair must look like A:B, got {pair}", 2)
    out = config_of(ctx).output_dir
    local_output(out, "align")
    try:
        total = count_views(out, max_images) * len(pairs)
        with make_progress(TextColumn("align"), BarColumn(), MofNCompleteColumn(),
                           TextColumn("views"), console=console, transient=True) as bar:
            task = bar.add_task("align views", total=total)
            table = run_alignment(out, pairs, min_cells, n_perm, seed,  # type: ignore[arg-type]
                                  max_images, lambda n: bar.advance(task, n))
    except (ValueError, FileNotFoundError) as err:
        fail(str(err))
    if max(table.column("images").to_pylist(), default=0) == 0:
        excluded = max(table.column("excluded_images").to_pylist(), default=0)
        fail(f"{out}: no view has >= {min_cells} supported cells ({excluded} excluded); "
             "nothing to align, no table written")
    try:
        written = write_alignment(out, table)
    except OSError as err:  # a full disk, a read-only stats/
        write_failed(err, "alignment table was")
    print_arrow(table, False)
    stdout.print(f"written: {written}", highlight=False)


def _consistency(ctx: typer.Context, max_offset_ms: float, max_rotation_deg: float,
                 max_pairs: int, max_views: int, as_json: bool) -> None:
    """`m3gd align --consistency`: sweep, write the table, print a summary (or JSON)."""
    from pipeline.analysis.align_consistency import (  # zarr, scipy: slow to import
        SweepGrid,
        run_consistency,
        summary_lines,
        write_consistency,
    )

    out = config_of(ctx).output_dir
    local_output(out, "align")
    grid = SweepGrid(max_offset_ms=max_offset_ms, step_ms=min(5.0, max_offset_ms),
                     max_rotation_deg=max_rotation_deg, step_deg=min(0.1, max_rotation_deg))
    try:
        result = run_consistency(config_of(ctx), grid, max_pairs=max_pairs,
                                 max_views=max_views)
    except (ValueError, FileNotFoundError) as err:
        fail(str(err).splitlines()[0])
    if result.table.num_rows == 0:
        fail(f"{out}: no camera has a usable view pair "
             f"({'; '.join(f'{k}: {v}' for k, v in sorted(result.skipped.items()))}); "
             "no table written")
    try:
        path = write_consistency(out, result.table)
    except OSError as err:  # a full disk, a read-only stats/
        write_failed(err, "consistency table was")
    if as_json:
        write_json({"rows": result.table.to_pylist(), "skipped": result.skipped,
                    "table": str(path)})
        return
    for line in summary_lines(result):
        stdout.print(line, highlight=False)
    stdout.print(f"written: {path}", highlight=False)
