"""Stage, run and report commands of the `m3gd` CLI (registered on the app)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from pipeline.cli_common import config_of, emit, fail, state, stdout
from schemas.config import M3GDConfig

SUMMARY_ROWS = 40

stats_app = typer.Typer(help="Query packet statistics (DuckDB over Parquet).",
                        no_args_is_help=True)


def _summary_table(summaries: list) -> Table:  # type: ignore[type-arg]
    """The final per-stage table: tasks (run, up to date, failed), outputs, rejects, time."""
    table = Table(title="m3gd run summary",
                  caption="tasks: per recording, camera or shard; outputs and rejected: views "
                          "(clips for the clips stage) written or refused this run")
    for col in ("stage", "tasks", "up to date", "failed", "outputs", "rejected", "seconds"):
        table.add_column(col, justify="left" if col == "stage" else "right")
    for s in summaries:
        table.add_row(s.name, str(s.items), str(s.skipped), str(len(s.failed)), str(s.done),
                      str(s.rejected), f"{s.seconds:.1f}")
    return table


def run_pipeline(cfg: M3GDConfig, local: bool, force: list[str], only: list[str],
                 progress: bool = True) -> int:
    """Run the stage graph; print the summary; return the count of failed items.

    Inputs and the output lock are checked before any worker starts, so a refused run
    costs nothing and says why in one line.
    """
    import pipeline.run.runner  # noqa: F401  (slow to import: before the lock, not under it)
    from dags.graph import stage_names
    from pipeline.run.lock import LockHeld, OutputLock

    unknown = sorted((set(force) | set(only)) - set(stage_names()))
    if unknown:
        fail(f"unknown stage {unknown[0]!r}; stages are {', '.join(stage_names())}", 2)
    _check_recordings(cfg)
    _check_cache_format(cfg)
    lock = OutputLock(cfg.output_dir)
    try:
        lock.acquire()
    except LockHeld as err:
        fail(str(err))
    except OSError as err:
        fail(f"{cfg.output_dir}: cannot be used as the output folder: "
             f"{err.strerror or err} ({err.filename or cfg.output_dir})")
    try:
        summaries = _run_locked(cfg, lock, local, force, only, progress)
    except KeyboardInterrupt:
        fail("interrupted: finished items are kept; run the same command again to resume", 130)
    finally:
        lock.release()  # also when interrupted between acquiring and the run
    stdout.print(_summary_table(summaries))
    failed = [(s.name, k, e) for s in summaries for k, e in s.failed.items()]
    for stage, key, err in failed:
        stdout.print(f"[red]failed[/] {stage} {key}: {err}", highlight=False)
    return len(failed)


def _run_locked(cfg: M3GDConfig, lock: Any, local: bool, force: list[str], only: list[str],
                progress: bool) -> list[Any]:
    """Start the executor and run the stages under the held `lock` (released by the caller)."""
    from dags.graph import STAGES
    from pipeline.run.runner import Runner, make_executor

    if lock.took_over is not None:
        stdout.print(f"took over the stale lock of a dead run ({lock.took_over.describe()})",
                     highlight=False)
    try:
        executor = make_executor(cfg, local)
    except OSError as err:
        fail(f"cannot start or reach the Dask cluster: {err}")
    if executor.dashboard_link:
        stdout.print(f"Dask dashboard: {executor.dashboard_link}")
    try:
        summaries: list[Any] = Runner(cfg, STAGES, progress=progress).run(
            executor, force=force, only=only, locked=True)
    finally:
        executor.close()
    return summaries


def _bars(ctx: typer.Context) -> bool:
    """Progress bars unless -q."""
    return state(ctx).verbosity >= 0


def _check_recordings(cfg: M3GDConfig) -> None:
    """Exit 2 naming the first configured recording that is not a folder."""
    for rec in cfg.ingest.recordings:
        if not Path(rec).is_dir():
            fail(f"ingest.recordings: {rec} is not a folder (a mission folder of bags)", 2)


def _check_cache_format(cfg: M3GDConfig) -> None:
    """Exit 2 with what to do when the output folder holds a cache of another format."""
    from pipeline.cache.store import DONE_DIR, cache_path
    from schemas.cache_io import node_attrs
    from schemas.cache_layout import check_root_attrs
    from schemas.versioning import UnknownSchemaVersion

    root = cache_path(cfg.output_dir)
    if not (root / "zarr.json").exists():
        return
    try:
        check_root_attrs(node_attrs(root), str(root))
    except (UnknownSchemaVersion, json.JSONDecodeError) as err:
        fail(f"{err}; to rebuild it: rm -r {root} {cfg.output_dir / DONE_DIR}", 2)


def register(app: typer.Typer) -> None:
    """Attach every implemented command to `app`."""
    app.add_typer(stats_app, name="stats")

    @app.command("run")
    def run(
        ctx: typer.Context,
        local: Annotated[bool, typer.Option("--local", help="Run in-process (debugging).")] = False,
        scheduler: Annotated[str | None, typer.Option(
            "--scheduler", help="Address of an existing dask.distributed scheduler.")] = None,
        workers: Annotated[int | None, typer.Option("--workers", help="LocalCluster size.")] = None,
        force: Annotated[list[str] | None, typer.Option(
            "--force", help="Redo STAGE and everything downstream of it.")] = None,
        only: Annotated[list[str] | None, typer.Option("--only", help="Run only STAGE.")] = None,
    ) -> None:
        """Run the stage graph (synth, ingest, select, encode, packets, stats, clips)."""
        cfg = config_of(ctx)
        dag = cfg.dag.model_copy(update={k: v for k, v in
                                         {"scheduler": scheduler, "workers": workers}.items()
                                         if v is not None})
        cfg = cfg.model_copy(update={"dag": dag})
        if run_pipeline(cfg, local, force or [], only or [], _bars(ctx)):
            raise typer.Exit(1)

    @app.command("demo")
    def demo(ctx: typer.Context) -> None:
        """The main job on the embedded defaults: synthesize, run every stage, report."""
        cfg = config_of(ctx)
        failed = run_pipeline(cfg, local=False, force=[], only=[], progress=_bars(ctx))
        from pipeline.report_plots import make_plots

        for path in make_plots(cfg.output_dir):
            stdout.print(f"plot: {path}", highlight=False)
        _print_outputs(cfg)
        if failed:
            raise typer.Exit(1)

    @stats_app.command("query")
    def stats_query(ctx: typer.Context, sql: str,
                    as_json: Annotated[bool, typer.Option("--json")] = False) -> None:
        """Run SQL over view_stats, cell_stats and clips."""
        from pipeline.stats.query import query

        try:
            table = query(config_of(ctx).output_dir, sql)
        except ValueError as err:
            fail(str(err).splitlines()[0])
        _print_arrow(table, as_json)

    @stats_app.command("summary")
    def stats_summary(ctx: typer.Context, name: Annotated[str | None, typer.Argument(
            help="dtau | occupancy | sparse_views | rejects (default: all)")] = None) -> None:
        """Canned reports: delta-tau per recording and camera, occupancy, sparse views."""
        from pipeline.stats.query import SUMMARIES, summary

        out = config_of(ctx).output_dir
        for key in [name] if name else list(SUMMARIES):
            try:
                table = summary(out, key)
            except ValueError as err:
                fail(str(err))
            stdout.print(f"[bold]{key}[/]")
            if table.num_rows == 0:
                stdout.print("(no rows)")
                continue
            _print_arrow(table.slice(0, SUMMARY_ROWS), False)
            if table.num_rows > SUMMARY_ROWS:
                stdout.print(f"(first {SUMMARY_ROWS} of {table.num_rows} rows; "
                             "`m3gd stats query` returns all)", highlight=False)

    _register_stage_commands(app)
    _register_analysis(app)
    _register_bench(app)


def _print_arrow(table, as_json: bool) -> None:  # type: ignore[no-untyped-def]
    """Print an Arrow table as JSON lines or a rich table."""
    if as_json:
        import json

        for row in table.to_pylist():
            stdout.print(json.dumps(row, default=str), highlight=False)
        return
    out = Table()
    for name in table.column_names:
        out.add_column(name)
    for row in table.to_pylist():
        out.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row.values()))
    stdout.print(out)


def _print_outputs(cfg: M3GDConfig) -> None:
    """Where the demo's outputs are."""
    out = cfg.output_dir
    for label, path in [("cache", out / "cache.zarr"), ("index", out / "index"),
                        ("statistics", out / "stats"), ("clips", out / "clips.parquet"),
                        ("plots", out / "plots"), ("manifest", out / "manifest.json")]:
        if path.exists():
            stdout.print(f"{label:>10}: {path}")


def _register_bench(app: typer.Typer) -> None:
    """`m3gd bench ...`: benchmarks that print ratios measured in one run."""
    bench = typer.Typer(help="Benchmarks (ratios against baselines measured in the same run).",
                        no_args_is_help=True)
    app.add_typer(bench, name="bench")

    @bench.command("cache")
    def bench_cache(as_json: Annotated[bool, typer.Option("--json")] = False,
                    views: int = 512, workdir: Path | None = None,
                    rss: Annotated[bool, typer.Option(help="Also measure worker peak RSS.")] = True
                    ) -> None:
        """Sharded Zarr cache against one .npy file per view."""
        from pipeline.bench.cache_bench import CacheBenchSpec, run_cache_bench

        result = run_cache_bench(CacheBenchSpec(views=views), workdir)
        if rss:
            from pipeline.bench.packing_bench import run_packing_rss_bench

            result["peak_rss_gb_per_worker"] = run_packing_rss_bench(repeats=1)[
                "peak_rss_gb_per_worker"]
        emit(result, as_json, "bench cache")

    @bench.command("packets")
    def bench_packets(as_json: Annotated[bool, typer.Option("--json")] = False,
                      repeats: int = 5) -> None:
        """Packet pooling against the per-cell loop, torch index_add_ and the gather floor."""
        from pipeline.bench.packets_bench import run_packets_bench

        emit(run_packets_bench(repeats), as_json, "bench packets")

    @bench.command("ingest")
    def bench_ingest(as_json: Annotated[bool, typer.Option("--json")] = False,
                     seconds: float = 12.0) -> None:
        """Ingest against the rosbags + imdecode floor; peak RSS at twice the length."""
        from pipeline.bench.ingest_bench import run_ingest_bench

        emit(run_ingest_bench(seconds), as_json, "bench ingest")

    @bench.command("packing")
    def bench_packing(as_json: Annotated[bool, typer.Option("--json")] = False) -> None:
        """Peak RSS of one worker encoding and packing a 64k-point sweep at C_u=1224."""
        from pipeline.bench.packing_bench import run_packing_rss_bench

        emit(run_packing_rss_bench(), as_json, "bench packing")

    @bench.command("dag")
    def bench_dag(as_json: Annotated[bool, typer.Option("--json")] = False,
                  seconds: float = 4.0, recordings: int = 4,
                  packet_items: Annotated[str, typer.Option(
                      help="packets.items: recording or shard_row.")] = "recording",
                  shard_views: Annotated[int, typer.Option(min=1)] = 64) -> None:
        """The stage graph on 2 Dask workers against 1, same recordings."""
        from pipeline.bench.dag_bench import run_dag_bench

        emit(run_dag_bench(seconds, recordings, packet_items, shard_views), as_json,
             "bench dag")

    @bench.command("synth")
    def bench_synth(as_json: Annotated[bool, typer.Option("--json")] = False,
                    seconds: float = 20.0, scene: str = "corridor") -> None:
        """Synthetic recording generation against the raycasting floor, same run."""
        from pipeline.bench.synth_bench import run as run_synth_bench

        emit(run_synth_bench(seconds, scene), as_json, "bench synth")

    @bench.command("costs")
    def bench_costs(as_json: Annotated[bool, typer.Option("--json")] = False,
                    runs: int = 3) -> None:
        """Per-item stage costs in one-thread workers, and the release estimate (scaling.md)."""
        from pipeline.bench.scaling_report import run_costs_bench

        result = run_costs_bench(runs)
        if as_json:
            stdout.print_json(json.dumps({k: v for k, v in result.items() if k != "markdown"},
                                         default=str))
        else:
            stdout.print(result["markdown"], highlight=False, markup=False)

    from pipeline.cli_model import register_model
    register_model(app, bench)


def _with_recordings(cfg: M3GDConfig, missions: list[Path] | None) -> M3GDConfig:
    """`cfg` with its recordings replaced by `missions` when given."""
    if not missions:
        return cfg
    ingest = cfg.ingest.model_copy(update={"recordings": list(missions)})
    return cfg.model_copy(update={"ingest": ingest})


def _register_stage_commands(app: typer.Typer) -> None:
    """`m3gd synth`, `m3gd ingest`, `m3gd select`: single stages of the graph."""

    @app.command("synth")
    def synth(
        ctx: typer.Context,
        out: Annotated[Path, typer.Argument(help="Folder to write the mission folder into.")],
        scene: Annotated[str, typer.Option(help="corridor|warehouse|forest|plaza")] = "corridor",
        seconds: Annotated[float | None, typer.Option(help="Recording length in s.")] = None,
        seed: Annotated[int | None, typer.Option(help="Random seed.")] = None,
        faults: Annotated[str | None, typer.Option(help="Comma-separated faults.")] = None,
        mission: Annotated[str | None, typer.Option(help="Mission name.")] = None,
    ) -> None:
        """Write a synthetic GrandTour-format recording with ground truth."""
        from pydantic import ValidationError

        from pipeline.synth.api import synthesize

        cfg = config_of(ctx).synth
        update = {k: v for k, v in {"seconds": seconds, "seed": seed}.items() if v is not None}
        if faults is not None:
            update["faults"] = [f.strip() for f in faults.split(",") if f.strip()]
        try:
            cfg = type(cfg).model_validate({**cfg.model_dump(), **update})
        except ValidationError as err:
            fail(f"bad synth option: {err.errors()[0]['loc']}: {err.errors()[0]['msg']}", 2)
        result = synthesize(out, cfg, scene, mission=mission)
        stdout.print(result)

    @app.command("ingest")
    def ingest(ctx: typer.Context, missions: Annotated[list[Path] | None, typer.Argument(
            help="Mission folders (default: the configured recordings).")] = None,
               local: Annotated[bool, typer.Option("--local")] = True) -> None:
        """Index recordings and write their rectified images into the cache."""
        cfg = _with_recordings(config_of(ctx), missions)
        if run_pipeline(cfg, local, [], ["ingest"], _bars(ctx)):
            raise typer.Exit(1)

    @app.command("select")
    def select(ctx: typer.Context, missions: Annotated[list[Path] | None, typer.Argument(
            help="Mission folders (default: the configured recordings).")] = None,
               local: Annotated[bool, typer.Option("--local")] = True) -> None:
        """Pick the nearest sweep of every image, Delta-tau and the LiDAR-to-camera chain."""
        cfg = _with_recordings(config_of(ctx), missions)
        if run_pipeline(cfg, local, [], ["select"], _bars(ctx)):
            raise typer.Exit(1)


def _register_analysis(app: typer.Typer) -> None:
    """`m3gd plot` and `m3gd align`."""

    @app.command("plot")
    def plot(ctx: typer.Context) -> None:
        """Write the analyst plots (PNG) of the output directory."""
        from pipeline.report_plots import make_plots

        out = config_of(ctx).output_dir
        if not out.is_dir():
            fail(f"{out}: no output directory; run the pipeline first (m3gd run)")
        paths = make_plots(out)
        for path in paths:
            stdout.print(str(path), highlight=False)
        if not paths:
            stdout.print(f"nothing to plot under {out} yet (no statistics, cache or benchmarks)")

    @app.command("align")
    def align(
        ctx: typer.Context,
        pair: Annotated[list[str] | None, typer.Option(
            help="Feature pair A:B, e.g. latents_l0:h (repeatable).")] = None,
        min_cells: int = 3, n_perm: int = 20, seed: int = 0,
        max_images: Annotated[int | None, typer.Option(help="Images per pair (all).")] = None,
    ) -> None:
        """2D-3D alignment diagnostics over the cache, each beside a permutation null."""
        from pipeline.align import run_alignment, write_alignment

        pairs = [tuple(p.split(":", 1)) for p in (pair or ["latents_l0:h"])]
        if any(len(p) != 2 for p in pairs):
            fail(f"--pair must look like A:B, got {pair}", 2)
        out = config_of(ctx).output_dir
        try:
            table = run_alignment(out, pairs, min_cells, n_perm, seed, max_images)  # type: ignore[arg-type]
        except (ValueError, FileNotFoundError) as err:
            fail(str(err))
        if max(table.column("images").to_pylist(), default=0) == 0:
            excluded = max(table.column("excluded_images").to_pylist(), default=0)
            fail(f"{out}: no view has >= {min_cells} supported cells ({excluded} excluded); "
                 "nothing to align, no table written")
        _print_arrow(table, False)
        stdout.print(f"written: {write_alignment(out, table)}", highlight=False)
