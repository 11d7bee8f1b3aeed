"""`m3gd bench ...`: benchmarks that print ratios against baselines measured in one run.

Every benchmark command is here: the pipeline's and the model's (`bench sampler`, `bench loader`,
`bench science`, `bench ddp`, which share option types with `cli.model`). Each benchmark module
is imported by its command only: they pull in zarr, dask, open3d or torch.

The product does not import this module: `m3gd` finds the group through the entry point
`bench = "bench.cli:GROUP"` of group `m3gd.commands`, declared by the `m3gd-bench` distribution
(`bench/pyproject.toml`, installed beside m3gd by `make install`; the m3gd wheel holds no
benchmark).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table

from cli.common import config_of, emit, fail, local_output, stdout, write_json
from cli.model import DeviceOpt, EmaOpt, JsonOpt, Mode, ThreadsOpt, _device, _threads

if TYPE_CHECKING:
    pass

HELP = "Benchmarks (ratios against baselines measured in the same run)."
JsonFlag = Annotated[bool, typer.Option("--json")]


def cache(as_json: JsonFlag = False, views: int = 512, workdir: Path | None = None,
          rss: Annotated[bool, typer.Option(help="Also measure worker peak RSS.")] = True
          ) -> None:
    """Sharded Zarr cache against one .npy file per view."""
    from bench.cache_bench import run_cache_bench
    from bench.cache_data import CacheBenchSpec
    from bench.packing_bench import run_packing_rss_bench

    result = run_cache_bench(CacheBenchSpec(views=views), workdir)
    if rss:
        result["peak_rss_gb_per_worker"] = run_packing_rss_bench(repeats=1)[
            "peak_rss_gb_per_worker"]
    emit(result, as_json, "bench cache")


def packets(as_json: JsonFlag = False, repeats: int = 5) -> None:
    """Packet pooling against the per-cell loop, torch index_add_ and the gather floor."""
    from bench.packets_bench import run_packets_bench

    emit(run_packets_bench(repeats), as_json, "bench packets")


def ingest(as_json: JsonFlag = False, seconds: float = 12.0) -> None:
    """Ingest against the rosbags + imdecode floor; peak RSS at twice the length."""
    from bench.ingest_bench import run_ingest_bench

    emit(run_ingest_bench(seconds), as_json, "bench ingest")


def packing(as_json: JsonFlag = False) -> None:
    """Peak RSS of one worker encoding and packing a 64k-point sweep at C_u=1224."""
    from bench.packing_bench import run_packing_rss_bench

    emit(run_packing_rss_bench(), as_json, "bench packing")


def dag(as_json: JsonFlag = False, seconds: float = 4.0, recordings: int = 4,
        packet_items: Annotated[str, typer.Option(
            help="packets.items: auto, recording or shard_row.")] = "auto",
        shard_views: Annotated[int, typer.Option(min=1)] = 64) -> None:
    """The stage graph on 2 Dask workers against 1, same recordings."""
    from bench.dag_bench import run_dag_bench
    from dags.graph import STAGES

    emit(run_dag_bench(STAGES, seconds, recordings, packet_items, shard_views), as_json,
         "bench dag")


def synth(as_json: JsonFlag = False, seconds: float = 20.0, scene: str = "corridor") -> None:
    """Synthetic recording generation against the raycasting floor, same run."""
    from bench.synth_bench import run as run_synth_bench

    emit(run_synth_bench(seconds, scene), as_json, "bench synth")


def tradeoffs(as_json: JsonFlag = False, seconds: float = 4.0, views: int = 60,
              workdir: Path | None = None) -> None:
    """What each speed / size knob saves and costs in depth accuracy (docs/tradeoffs.md)."""
    from bench.tradeoffs import run_tradeoffs

    emit(run_tradeoffs(workdir, seconds, max_views=views), as_json, "bench tradeoffs")


def costs(as_json: JsonFlag = False, runs: int = 3) -> None:
    """Per-item stage costs in one-thread workers, and the release estimate (scaling.md)."""
    from bench.scaling_report import run_costs_bench

    result = run_costs_bench(runs)
    if as_json:
        write_json({k: v for k, v in result.items() if k != "markdown"})
    else:
        stdout.print(result["markdown"], highlight=False, markup=False)


def fuzz(as_json: JsonFlag = False, cases: int = 40, seconds: float = 120.0, seed: int = 0,
         lock_trials: int = 3, lock_starts: int = 8, workdir: Path | None = None,
         compression: Annotated[str, typer.Option(help="chunks of the fuzzed bags: roslz4 "
                                "(rosbag record's LZ4, checksummed), lz4 (no checksum), none"
                                )] = "roslz4",
         variants: Annotated[str | None, typer.Option(
             help="comma-separated sensor variants the cases take turns on (`all`: every "
                  "one; default: the default recording)")] = None,
         hf_cases: Annotated[int, typer.Option(help="Hugging Face store cases (a cut or "
                                               "flipped chunk, ingested in a child process)"
                                               )] = 12,
         cache_flips: Annotated[int, typer.Option(
             help="cache chunks with flipped bits, read back by every reader")] = 50,
         ) -> None:  # fmt: skip
    """Damaged bags against their clean twin: crashes, silent losses, damage cached (goal 0)."""
    import tempfile

    from bench.fuzz import run_fuzz
    from pipeline.synth.variants import VARIANTS

    chosen = None
    if variants:
        chosen = list(VARIANTS) if variants == "all" else [
            v.strip() for v in variants.split(",") if v.strip()]
        unknown = sorted(set(chosen) - set(VARIANTS))
        if unknown:
            fail(f"unknown sensor variant(s) {unknown}; known: {', '.join(VARIANTS)}", 2)
    if workdir is not None:  # a folder to create, like any output folder
        workdir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        result = run_fuzz(Path(tmp), cases, seconds, seed, lock_trials, lock_starts,
                          compression, chosen, hf_cases, cache_flips)  # type: ignore[arg-type]
    emit(result, as_json, "bench fuzz")


def storage(as_json: JsonFlag = False, output: Annotated[Path | None, typer.Option(
        help="A pipeline output dir; default: build a tiny one in a temporary directory."
        )] = None, rounds: Annotated[int, typer.Option(min=1)] = 3) -> None:
    """Clip reads from S3 (a local moto server) against local disk; requests per clip."""
    from bench.storage_bench import run
    from dags.graph import STAGES

    emit(run(STAGES, output, rounds), as_json, "bench storage")


def variants(as_json: JsonFlag = False,
             names: Annotated[str | None, typer.Option(
                 "--only", help="comma-separated variant names, groups (sensors, time, rig, tf, "
                 "sources, geometry, point_time) or shell patterns (default: all)")] = None,
             seconds: float = 3.0, workdir: Path | None = None) -> None:
    """Every sensor and rig variant through synth, ingest, select, packets and accuracy: false
    rejects, views kept against the default synth, depth abs-rel, silent losses, and whether
    the configuration `m3gd inspect --write-config` writes for it runs and keeps the views."""
    import tempfile

    from bench.variants import run_variants

    chosen = [n.strip() for n in names.split(",") if n.strip()] if names else None
    if workdir is not None:  # a folder to create, like any output folder
        workdir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        result = run_variants(Path(tmp), chosen, {"seconds": seconds})
    emit(result, as_json, "bench variants")


def view(as_json: JsonFlag = False,
         seconds: float = 10.0, points: int = 16384, repeats: int = 3) -> None:
    """Writing the .rrd of a recording against reading its views from the cache."""
    from bench.view_bench import run_view_bench
    from dags.graph import STAGES

    emit(run_view_bench(STAGES, seconds, points, repeats), as_json, "bench view")


def loader(
    as_json: JsonOpt = False,
    cache: Annotated[Path | None, typer.Option(
        help="A pipeline output dir (cache.zarr + clips.parquet); default: build a tiny "
             "one with the real pipeline in a temporary directory.")] = None,
    batch_size: Annotated[int, typer.Option(min=1)] = 4,
    workers: Annotated[int, typer.Option(min=0, help="Workers of the second run.")] = 2,
    min_clips: Annotated[int, typer.Option(min=1, help="Clips timed per run.")] = 64,
    model_steps: Annotated[int, typer.Option(min=1, help="Timed trainer steps.")] = 5,
    mode: Annotated[Mode, typer.Option(help="Packet mode read and trained.")] = Mode.full,  # type: ignore[attr-defined]  # a functional StrEnum
) -> None:
    """Loader clips/s against the tiny model's training clips/s (goal: loader >= 5x)."""
    from bench.loader_bench import LoaderBenchSpec, run_loader_bench
    from dags.graph import STAGES

    spec = LoaderBenchSpec(batch_size=batch_size, mode=mode.value, workers=workers,
                           min_clips=min_clips, model_steps=model_steps)
    try:
        result = run_loader_bench(spec, STAGES, cache)
    except (FileNotFoundError, ValueError) as err:
        fail(str(err))
    if as_json:
        write_json(result)
        return
    emit({k: v for k, v in result.items() if not isinstance(v, dict)}, False,
         "bench loader")


def science(
    ctx: typer.Context,
    as_json: JsonOpt = False,
    quick: Annotated[bool, typer.Option(
        "--quick", help="Minutes: tiny cache, 30 steps, full and no_lidar, one seed.")] = False,
    narrow: Annotated[bool, typer.Option(
        "--narrow", help="Narrow baselines (1-6 frames between views, 2000 steps): full vs "
                         "no_lidar.")] = False,
    workdir: Annotated[Path | None, typer.Option(
        help="Cache, per-run results (reused), plots (<output_dir>/science).")] = None,
    cache: Annotated[Path | None, typer.Option(
        help="Reuse a science cache (a pipeline output dir) instead of building one.")] = None,
    jobs: Annotated[int, typer.Option(min=1, help="Runs trained at once (processes).")] = 1,
    only_finished: Annotated[bool, typer.Option(
        "--only-finished", help="Aggregate the runs already in --workdir; train none.")] = False,
    suite: Annotated[str, typer.Option(
        help="default: packet modes and the speed-accuracy trade; paper: the paper's "
             "controls (learnable packet, freeze / finetune, all-views loss, LiDAR dropout, "
             "M targets, the delta-tau channel and clock offsets).")] = "default",
    steps: Annotated[int | None, typer.Option(
        min=1, help="Training steps per run (overrides the preset's).")] = None,
    seeds: Annotated[int | None, typer.Option(
        min=1, help="Seeds per row (0 .. N-1; overrides the preset's).")] = None,
    rows: Annotated[str | None, typer.Option(
        help="--suite paper*: only these comma-separated rows (and those they start from), "
             "without the M-target table; e.g. no_lidar,full,warp,full_warp.")] = None,
    device: Annotated[str | None, typer.Option(
        "--device", help="auto | cpu | cuda | cuda:N | mps: where the runs train and score "
                         "(cpu when not given: the figures' machine).")] = None,
    recordings: Annotated[str | None, typer.Option(
        help="--suite paper-cpu: the data-scaling table at these comma-separated training "
             "recording counts (multiples of 4, e.g. 8,32,128; rows no_lidar,full,warp_x "
             "unless --rows), scored on held-out recordings of unseen seeds.")] = None,
    point_seeds: Annotated[str | None, typer.Option(
        help="With --recordings: training seeds per point, comma-separated (e.g. 3,3,1; "
             "default --seeds or the suite's 3 at every point).")] = None,
) -> None:
    """Model vs the trivial baselines (copy-nearest-source, mean latent, mean training
    image), LiDAR effect over seeds, speed-accuracy trade; with --suite paper the paper's
    controls (docs/benchmarks_model.md)."""
    from dataclasses import replace

    from bench.cli_science import paper_suite, scaling_table
    from bench.science import FULL, HEADLINE, NARROW, QUICK, run_science
    from dags.graph import STAGES
    from pipeline.analysis.figures import save_bench

    cfg = config_of(ctx)
    preset = QUICK if quick else NARROW if narrow else FULL
    if steps is not None:
        preset = replace(preset, spec=replace(preset.spec, steps=steps,
                                              val_every=max(1, min(preset.spec.val_every,
                                                                   steps // 2))))
    if seeds is not None:
        preset = replace(preset, seeds=tuple(range(seeds)))
    dev = "cpu" if device is None else str(_device(cfg, device))  # the figures' machine
    if suite not in ("default", "paper", "paper-cpu"):
        fail(f"--suite {suite!r}: one of default, paper, paper-cpu")
    if recordings is not None:
        if suite != "paper-cpu":
            fail("--recordings: the data-scaling table is of --suite paper-cpu")
        scaling_table(cfg, workdir, jobs, not only_finished, as_json, recordings,
                 point_seeds or (None if seeds is None else ",".join(
                     [str(seeds)] * len(recordings.split(",")))), rows, steps, dev)
        return
    if suite.startswith("paper"):
        paper_suite(cfg, preset, quick, suite == "paper-cpu", workdir, cache, jobs,
               not only_finished, as_json, steps, seeds, rows, dev)
        return
    preset = replace(preset, spec=replace(preset.spec, device=dev))
    result = run_science(preset, workdir or cfg.layout.science, STAGES,
                         cache, jobs, not only_finished)
    save_bench(cfg.output_dir, "science", result)
    emit({k: result[k] for k in HEADLINE if k in result}, as_json, "bench science")


def ddp(
    ctx: typer.Context,
    as_json: JsonOpt = False,
    workdir: Annotated[Path | None, typer.Option(
        help="Cache, runs and samples (<output_dir>/bench_ddp).")] = None,
    cache: Annotated[Path | None, typer.Option(
        help="A pipeline output dir to train on (default: build a tiny one).")] = None,
    demo: Annotated[Path | None, typer.Option(
        help="A demo output dir with train/full: sample and eval its checkpoint.")] = None,
    steps: Annotated[int, typer.Option(min=2, help="Updates of each training run.")] = 20,
    paper_step: Annotated[bool, typer.Option(
        "--paper-step", help="Only time one update at the paper's sizes (gld preset, C 1536, "
                             "C_u 1224; minutes, ~3 GB).")] = False,
) -> None:
    """2 ranks (torchrun, gloo) against 1, the deal of clips, checkpoint kill windows, sample
    memory and eval time (docs/training_gpus.md)."""
    from bench.ddp_bench import DdpBenchSpec, run_ddp_bench
    from dags.graph import STAGES
    from pipeline.analysis.figures import save_bench

    cfg = config_of(ctx)
    if paper_step:
        from bench.paper_step import run_paper_step

        step = run_paper_step()
        save_bench(cfg.output_dir, "paper_step", step)
        emit({k: v for k, v in step.items() if not isinstance(v, list)}, as_json,
             "one update at the paper's sizes (1 CPU thread)")
        return
    try:
        result = run_ddp_bench(DdpBenchSpec(steps=steps), STAGES,
                               workdir or cfg.output_dir / "bench_ddp", cache, demo)
    except (OSError, RuntimeError, ValueError) as err:
        fail(str(err).splitlines()[0] if str(err) else type(err).__name__)
    save_bench(cfg.output_dir, "ddp", result)
    emit({k: v for k, v in result.items() if not isinstance(v, dict)}, as_json, "bench ddp")


def sampler(
    ctx: typer.Context,
    as_json: JsonOpt = False,
    quick: Annotated[bool, typer.Option(
        "--quick", help="Small grid (K 1, 2; M 2) at small sizes, for tests.")] = False,
    checkpoint: Annotated[Path | None, typer.Option(
        help="Checkpoint: its sizes and EMA weights; adds PSNR/SSIM against K.")] = None,
    clips: Annotated[int, typer.Option(
        min=1, help="Eval clips per K for the quality table (with --checkpoint).")] = 8,
    repeats: Annotated[int | None, typer.Option(min=1, help="Timed runs per cell.")] = None,
    ema: EmaOpt = False,
    threads: ThreadsOpt = 1,
    device: DeviceOpt = None,
) -> None:
    """Latency, latency per target and peak memory against K and M (paper Table 7)."""
    from bench.sampler_bench import run_sampler_with_quality
    from schemas.errors import DataError

    _threads(threads)
    cfg = config_of(ctx)
    local_output(cfg.output_dir, "bench sampler")
    dev = _device(cfg, device)
    try:
        result = run_sampler_with_quality(cfg, quick, checkpoint, clips, repeats, ema, dev)
    except DataError as err:
        fail(str(err))
    from pipeline.analysis.figures import save_bench

    save_bench(cfg.output_dir, "sampler", result)  # `m3gd plot` draws its speed-accuracy
    if as_json:
        write_json(result)
        return
    _print_sampler(result)


def _print_sampler(result: dict[str, Any]) -> None:
    """The latency table (K x M) and, if present, the PSNR/SSIM against K."""
    table = Table(title=f"bench sampler ({result['weights']} weights)")
    table.caption = ("peak +MB: resident memory above the RSS at sampler entry; rel L2: distance"
                     " of z_0 to a many-step reference solve")
    for col in ("K", "M", "latency s", "per target s", "peak +MB", "rel L2 to ref"):
        table.add_column(col, justify="right")
    for k, row in result["latency"].items():
        for m, cell in row.items():
            table.add_row(k, m, f"{cell['latency_s']:.3f}", f"{cell['latency_per_target_s']:.3f}",
                          f"{cell['peak_mem_mb']:.0f}",
                          f"{result['quality_rel_l2_to_reference'][k][m]:.3g}")
    stdout.print(table)
    for m, a in result["adaptive"].items():
        stdout.print(f"adaptive M={m}: {a['steps_taken']}/{a['max_steps']} steps, "
                     f"{a['latency_s']:.3f} s (fixed {a['fixed_latency_s']:.3f} s), rel L2 "
                     f"{a['rel_l2_to_reference']:.3g} (fixed {a['fixed_rel_l2_to_reference']:.3g})",
                     highlight=False, soft_wrap=True)
    for k, q in result.get("quality_psnr_ssim", {}).items():
        stdout.print(f"K={k}: PSNR {q['psnr_mean']:.2f} dB, SSIM {q['ssim_mean']:.3f} over "
                     f"{q['targets']} targets", highlight=False, soft_wrap=True)


GROUP: tuple[str, dict[str, Any]] = (HELP, {
    "cache": cache, "packets": packets, "ingest": ingest,
    "packing": packing, "dag": dag, "synth": synth, "costs": costs,
    "fuzz": fuzz, "variants": variants,
    "storage": storage,
    "sampler": sampler, "loader": loader,
    "tradeoffs": tradeoffs, "view": view,
    "science": science, "ddp": ddp,
})
"""The `bench` command group, in `m3gd bench --help`'s order: its help and name -> command (the
entry point `m3gd.commands: bench` that `cli.app` attaches)."""
