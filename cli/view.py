"""Looking at the data: `m3gd view` (a Rerun recording) and `m3gd report` (one HTML page). The
logic lives in pipeline.analysis.view and pipeline.analysis.report; each is imported by its
command only (rerun, duckdb, matplotlib)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.common import (
    config_of,
    console,
    fail,
    local_output,
    refuse_foreign_output,
    rerun_file,
    stdout,
    write_failed,
)


def view(
    ctx: typer.Context,
    out: Annotated[Path | None, typer.Option("--out", "-o", help=".rrd path (default "
                                             "<output>/view/<recording>.rrd).")] = None,
    recording: Annotated[str | None, typer.Option(help="Recording (the first).")] = None,
    camera: Annotated[list[str] | None, typer.Option(help="Camera (repeatable; all).")] = None,
    start: Annotated[float | None, typer.Option(help="Seconds after the first image.")] = None,
    end: Annotated[float | None, typer.Option(help="Seconds after the first image.")] = None,
    max_views: Annotated[int | None, typer.Option(min=0, help="At most this many views, the "
                                                  "earliest (all).")] = None,
    max_points: Annotated[int | None, typer.Option(min=1, help="Points per cloud (all).")
                          ] = None,
    jpeg_quality: Annotated[int | None, typer.Option(min=1, max=100, help="Store images as "
                                                     "JPEG (raw).")] = None,
    spawn: Annotated[bool, typer.Option(help="Open the viewer if a display exists.")] = False,
) -> None:
    """Rerun recording (.rrd) of one recording: images, LiDAR, packets, trajectory, rejects."""
    from pipeline.analysis.view.command import run_view
    from pipeline.analysis.view.writer import ViewOptions
    from pipeline.run.progress import make_progress

    local_output(config_of(ctx).output_dir, "view")
    if out is not None:
        refuse_foreign_output(out, config_of(ctx), "Rerun recording", rerun_file)
    opts = ViewOptions(recording, camera, start, end, max_views, max_points, jpeg_quality)
    try:
        with make_progress(console=console, transient=True) as bar:
            task = bar.add_task("view views")
            lines = run_view(config_of(ctx), opts, out, spawn,
                             lambda done, total: bar.update(task, completed=done, total=total))
    except (ValueError, FileNotFoundError, LookupError) as err:
        fail(str(err))
    except OSError as err:  # a full disk, a read-only folder
        write_failed(err, "Rerun recording was")
    stdout.print("\n".join(lines), highlight=False, soft_wrap=True)


def report(ctx: typer.Context, out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="HTML path (default <output>/report.html).")] = None,
           plots: Annotated[bool, typer.Option(help="Write the plots first (as m3gd plot).")
                                ] = True,
           ) -> None:
    """One self-contained static HTML page of the output directory."""
    from pipeline.analysis.report.build import run_report

    cfg = config_of(ctx)
    local_output(cfg.output_dir, "report")
    try:
        lines = run_report(cfg.output_dir, out, plots, cfg.select.max_abs_dt_s)
    except FileNotFoundError as err:
        fail(str(err))
    except OSError as err:  # a full disk, a read-only folder
        write_failed(err, "report was")
    stdout.print("\n".join(lines), highlight=False, soft_wrap=True)
