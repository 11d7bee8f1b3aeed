"""Stage commands of the `m3gd` CLI: run, demo and the single stages synth, ingest, select."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import ValidationError
from rich.table import Table

from cli.common import config_of, console, fail, local_output, state, stdout, styled
from pipeline.run.lock import LockHeld, OutputUnusable, acquire_output
from pipeline.run.service import RunEvents, release
from pipeline.synth.variants import variant_help
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.stages import INGEST, SELECT, PostCheck, with_check
from store.object_store import StorageError, display

MissionsArg = Annotated[list[Path] | None, typer.Argument(
    help="Mission folders (default: the configured recordings).")]


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
                 progress: bool = True, allow_empty: bool = False,
                 break_lock: bool = False, verify: bool = False) -> int:
    """Run the stage graph under the run policy (`pipeline.run.service`); print the summary;
    return the count of failed items (and, unless `allow_empty`, of recordings left without
    any usable view). A refused or stopped run exits with its one line."""
    from dags.run import run_graph
    from pipeline.run.service import INTERRUPTED, RunError, RunRequest
    from schemas.config import synthetic_refusal

    refusal = synthetic_refusal(cfg)
    if refusal is not None:
        fail(refusal, 2)
    request = RunRequest(local=local, force=tuple(force), only=tuple(only), progress=progress,
                         break_lock=break_lock, verify=verify)
    try:
        outcome = run_graph(cfg, request, _PrintedEvents(), console)
    except RunError as err:
        fail(str(err), err.exit_code)
    except KeyboardInterrupt:
        fail(INTERRUPTED, 130)
    stdout.print(_summary_table(outcome.summaries))
    if any(s.name in with_check(PostCheck.GEOMETRY_VERDICT) for s in outcome.summaries):
        from pipeline.analysis.geometry_check import verdict_lines
        from schemas.missions import recording_names

        for line in verdict_lines(cfg.output_dir, recording_names(cfg)):
            stdout.print(line, markup=False, highlight=False)
    for stage, key, error in outcome.failed:
        stdout.print(styled(("failed", "red"), f" {stage} {key}: {error}"))
    for line in outcome.empty:
        stdout.print(styled(("allowed", "yellow"), f" {line}") if allow_empty else
                     styled(("failed", "red"), f" {line} (--allow-empty accepts this)"))
    return outcome.failures(allow_empty)


def release_lock(lock: Any, out: Path) -> None:
    """Release the output lock; if that fails (the store went away), say so in one line
    with what to do instead of raising over the run's own outcome."""
    release(lock, out, _PrintedEvents())


class _PrintedEvents(RunEvents):
    """The run's messages, printed."""

    def took_over(self, holder: str) -> None:
        stdout.print(f"took over the stale lock of a dead run ({holder})", highlight=False)

    def dashboard(self, link: str) -> None:
        stdout.print(f"Dask dashboard: {link}")

    def verified(self, result: Any) -> None:
        _print_verify(*result)

    def lock_not_released(self, out: Path, err: Exception) -> None:
        console.print(styled(("error:", "bold red"), f" could not release the lock of "
                             f"{display(out)}: {err}; once it is reachable: m3gd unlock "
                             f"{display(out)}"), soft_wrap=True)  # fmt: skip


def _print_verify(report: Any, forgotten: list[Any]) -> int:
    """Print each corrupt chunk, missing array, stale normalization and the items forgotten
    so that a run redoes them; return the count of damaged things."""
    for chunk in report.corrupt:
        stdout.print(styled(("corrupt", "red"), f" {chunk.line()}"))
    for line in [m.line() for m in report.missing] + [report.stale_norm or ""]:
        if line:
            stdout.print(styled(("damaged", "red"), f" {line}"))
    for line in [f.line() for f in report.files] + [report.manifest or ""]:
        if line:
            stdout.print(styled(("damaged", "red"), f" {line}"))
    for item in forgotten:
        stdout.print(f"redo: {item}", highlight=False)
    for array in report.unchecked:
        stdout.print(styled(("not checked", "yellow"),
                            f" {array}: its chunks carry no checksum"))  # fmt: skip
    views = sum(c.views[1] - c.views[0] + 1 for c in report.corrupt)
    stdout.print(f"verify: {report.checked} stored chunks checked; " + (
        f"corrupt: {views} view(s) in {len(report.corrupt)} place(s), redone by the next run"
        if report.corrupt else "none corrupt") + f"; {report.files_checked} tables and metadata "
        f"files checked, {len(report.files)} damaged", highlight=False)  # fmt: skip
    return (len(report.corrupt) + len(report.missing) + bool(report.stale_norm)
            + len(report.files) + bool(report.manifest))


def verify(ctx: typer.Context, out: Annotated[Path | None, typer.Argument(
        help="Output folder (default: the configured output_dir).")] = None) -> None:
    """Check every stored cache chunk against its CRC32C; a corrupt chunk is named (file,
    array, views) and its items are marked for the next run to redo. Exit 1 if any."""
    from dags.run import verify_cache

    folder = out or config_of(ctx).output_dir
    local_output(folder, "verify")
    try:
        lock = acquire_output(folder)
    except (LockHeld, StorageError, OutputUnusable) as err:
        fail(str(err))
    try:
        corrupt = _print_verify(*verify_cache(folder))
    except DataError as err:  # e.g. the manifest could not be written (a full disk)
        fail(f"verify stopped: {err}")
    finally:
        release_lock(lock, folder)
    if corrupt:
        raise typer.Exit(1)


def _bars(ctx: typer.Context) -> bool:
    """Progress bars unless -q."""
    return state(ctx).verbosity >= 0


def run(
    ctx: typer.Context,
    local: Annotated[bool, typer.Option("--local", help="Run in-process (debugging).")] = False,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Address of an existing dask.distributed scheduler.")] = None,
    workers: Annotated[int | None, typer.Option("--workers", help="LocalCluster size.")] = None,
    force: Annotated[list[str] | None, typer.Option(
        "--force", help="Redo STAGE and everything downstream of it.")] = None,
    only: Annotated[list[str] | None, typer.Option("--only", help="Run only STAGE.")] = None,
    allow_empty: Annotated[bool, typer.Option(
        "--allow-empty", help="Exit 0 even if a recording has no usable view.")] = False,
    break_lock: Annotated[bool, typer.Option(
        "--break-lock", help="Take over a lock left by a run on another host.")] = False,
    verify: Annotated[bool, typer.Option(
        "--verify", help="First check every cache chunk's CRC32C and redo what is corrupt."
    )] = False,
    accept_geometry: Annotated[list[str] | None, typer.Option(
        "--accept-geometry", metavar="CAMERA", help="Accept a `failed` geometry verdict of "
        "CAMERA (a camera name or RECORDING/CAMERA; geometry.accept): exit 0 for it.")] = None,
) -> None:
    """Run the stage graph (synth, ingest, select, encode, packets, geometry, stats, clips)."""
    cfg = config_of(ctx)
    dag = cfg.dag.model_copy(update={k: v for k, v in
                                     {"scheduler": scheduler, "workers": workers}.items()
                                     if v is not None})
    geometry = cfg.geometry.model_copy(update={
        "accept": [*cfg.geometry.accept, *(accept_geometry or [])]})
    cfg = cfg.model_copy(update={"dag": dag, "geometry": geometry})
    if run_pipeline(cfg, local, force or [], only or [], _bars(ctx), allow_empty, break_lock,
                    verify):
        raise typer.Exit(1)


def unlock(ctx: typer.Context, out: Annotated[Path | None, typer.Argument(
        help="Output folder (default: the configured output_dir).")] = None) -> None:
    """Remove the lock of an output folder left by a run that is gone (e.g. on another host)."""
    from pipeline.run.lock import unlock as remove_lock

    folder = out or config_of(ctx).output_dir
    try:
        old = remove_lock(folder)
    except (LockHeld, StorageError) as err:
        fail(str(err))
    stdout.print(f"{display(folder)}: " + (f"removed the lock of {old.describe()}" if old else
                                  "no lock to remove"), highlight=False)


def demo(ctx: typer.Context) -> None:
    """The main job on the embedded defaults: synthesize, run every stage, report."""
    cfg = config_of(ctx).model_copy(update={"synthetic": True})  # the demo asks for it
    local_output(cfg.output_dir, "demo")
    failed = run_pipeline(cfg, local=False, force=[], only=[], progress=_bars(ctx))
    from pipeline.analysis.figures import make_plots  # matplotlib: slow to import

    for path in make_plots(cfg.output_dir, cfg.select.max_abs_dt_s):
        stdout.print(f"plot: {path}", highlight=False)
    _print_outputs(cfg)
    if failed:
        raise typer.Exit(1)


def _print_outputs(cfg: M3GDConfig) -> None:
    """Where the demo's outputs are."""
    for label, path in cfg.layout.outputs():
        if path.exists():
            stdout.print(f"{label:>10}: {path}")


def _with_recordings(cfg: M3GDConfig, missions: list[Path] | None) -> M3GDConfig:
    """`cfg` with its recordings replaced by `missions` when given."""
    if not missions:
        return cfg
    ingest = cfg.ingest.model_copy(update={"recordings": list(missions)})
    return cfg.model_copy(update={"ingest": ingest})


def _fault_names() -> list[str]:
    """Names `synth.faults` accepts (from the config schema)."""
    import typing

    from schemas.config import SynthConfig

    (literal,) = typing.get_args(SynthConfig.model_fields["faults"].annotation)
    return list(typing.get_args(literal))


FAULTS_HELP = "Comma-separated faults to inject: " + ", ".join(_fault_names()) + "."


def _synth_table(result: Any) -> Table:
    """What `synth` wrote, one row per figure."""
    table = Table(title=f"synthesized mission {result.mission}", show_header=False)
    table.add_column("what")
    table.add_column("value", overflow="fold")
    table.add_row("mission folder", str(result.mission_dir))
    for suffix, path in sorted(result.bags.items()):
        table.add_row(f"bag {suffix}", path.name)
    table.add_row("images", ", ".join(f"{cam} {n}" for cam, n in sorted(result.images.items())))
    table.add_row("sweeps", str(result.sweeps))
    table.add_row("odometry poses", str(result.odometry))
    table.add_row("ground truth", str(result.groundtruth_dir))
    if result.ros2_dir is not None:
        table.add_row("ROS2 copies", str(result.ros2_dir))
    table.add_row("faults", ", ".join(str(f.get("kind", f)) for f in result.faults) or "none")
    table.add_row("seconds", f"{result.seconds_elapsed:.1f}")
    return table


VARIANT_HELP = ("Sensor variant (synth.variant), by group: " + variant_help()
                + " (pipeline/synth/variants.py).")
"""The variant names for --help (tests check it lists every one of synth.variant)."""


def synth(
    ctx: typer.Context,
    out: Annotated[Path | None, typer.Argument(
        help="Folder to write the mission folder into (default: <output_dir>/recordings, "
             "where `m3gd run` looks).")] = None,
    scene: Annotated[str, typer.Option(help="corridor|warehouse|forest|plaza")] = "corridor",
    seconds: Annotated[float | None, typer.Option(help="Recording length in s.")] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed.")] = None,
    faults: Annotated[str | None, typer.Option(help=FAULTS_HELP)] = None,
    mission: Annotated[str | None, typer.Option(
        help="Mission name (default synth_<scene>_s<seed>, as `m3gd run` names it).")] = None,
    fmt: Annotated[str | None, typer.Option("--format", help="rosbag|hf-zarr")] = None,
    variant: Annotated[str | None, typer.Option(help=VARIANT_HELP)] = None,
    second_lidar: Annotated[bool | None, typer.Option(
        "--second-lidar", help="Also carry a second LiDAR (/livox/lidar, frame livox_frame; "
        "synth.second_lidar).")] = None,
) -> None:
    """Write a synthetic GrandTour-format recording with ground truth."""
    from pipeline.synth.api import synthesize  # open3d: slow to import

    full = config_of(ctx)
    cfg = full.synth
    update: dict[str, Any] = {k: v for k, v in {"seconds": seconds, "seed": seed, "format": fmt,
                                "variant": variant, "second_lidar": second_lidar}.items()
              if v is not None}
    if faults is not None:
        update["faults"] = [f.strip() for f in faults.split(",") if f.strip()]
    try:
        cfg = type(cfg).model_validate({**cfg.model_dump(), **update})
    except ValidationError as err:
        first = err.errors()[0]
        key = ".".join(str(p) for p in first["loc"][:1])
        hint = f" (faults: {', '.join(_fault_names())})" if key == "faults" else ""
        fail(f"bad synth option --{key}: {first['input']!r}: {first['msg']}{hint}", 2)
    try:
        result = synthesize(out if out is not None else full.layout.recordings, cfg, scene,
                            mission=mission)
    except (ValueError, FileExistsError) as err:  # a bad mission name, a folder not ours
        fail(str(err), 2)
    stdout.print(_synth_table(result))


def ingest(ctx: typer.Context, missions: MissionsArg = None,
           local: Annotated[bool, typer.Option("--local")] = True) -> None:
    """Index recordings and write their rectified images into the cache."""
    _single_stage(ctx, missions, local, INGEST.name)


def select(ctx: typer.Context, missions: MissionsArg = None,
           local: Annotated[bool, typer.Option("--local")] = True) -> None:
    """Pick the nearest sweep of every image, Delta-tau and the LiDAR-to-camera chain."""
    _single_stage(ctx, missions, local, SELECT.name)


def _single_stage(ctx: typer.Context, missions: list[Path] | None, local: bool,
                  stage: str) -> None:
    """Run one stage over `missions` (or the configured recordings); exit 1 on a failure."""
    cfg = _with_recordings(config_of(ctx), missions)
    if run_pipeline(cfg, local, [], [stage], _bars(ctx)):
        raise typer.Exit(1)
