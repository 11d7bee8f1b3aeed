"""`m3gd bench loader` and `m3gd bench science`: the model benchmarks that build their own data
(the sampler bench stays in cli.model, beside the scoring helpers it shares)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from bench.science import SciencePreset
    from schemas.config import M3GDConfig

from cli.common import config_of, emit, fail, stdout
from cli.model import JsonOpt, Mode


def bench_loader(
    as_json: JsonOpt = False,
    cache: Annotated[Path | None, typer.Option(
        help="A pipeline output dir (cache.zarr + clips.parquet); default: build a tiny "
             "one with the real pipeline in a temporary directory.")] = None,
    batch_size: Annotated[int, typer.Option(min=1)] = 4,
    workers: Annotated[int, typer.Option(min=0, help="Workers of the second run.")] = 2,
    min_clips: Annotated[int, typer.Option(min=1, help="Clips timed per run.")] = 64,
    model_steps: Annotated[int, typer.Option(min=1, help="Timed trainer steps.")] = 5,
    mode: Annotated[Mode, typer.Option(help="Packet mode read and trained.")] = Mode.full,
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
        stdout.print_json(json.dumps(result, default=str))
        return
    emit({k: v for k, v in result.items() if not isinstance(v, dict)}, False,
         "bench loader")


def bench_science(
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
) -> None:
    """Model vs the trivial baselines (copy-nearest-source, mean latent, mean training
    image), LiDAR effect over seeds, speed-accuracy trade; with --suite paper the paper's
    controls (docs/benchmarks_model.md)."""
    from dataclasses import replace

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
    if suite not in ("default", "paper", "paper-cpu"):
        fail(f"--suite {suite!r}: one of default, paper, paper-cpu")
    if suite.startswith("paper"):
        _paper(cfg, preset, quick, suite == "paper-cpu", workdir, cache, jobs,
               not only_finished, as_json, steps, seeds)
        return
    result = run_science(preset, workdir or cfg.layout.science, STAGES,
                         cache, jobs, not only_finished)
    save_bench(cfg.output_dir, "science", result)
    emit({k: result[k] for k in HEADLINE if k in result}, as_json, "bench science")


def _paper(cfg: M3GDConfig, preset: SciencePreset, quick: bool, cpu: bool,
           workdir: Path | None, cache: Path | None, jobs: int, train_missing: bool,
           as_json: bool, steps: int | None, seeds: int | None) -> None:
    """`m3gd bench science --suite paper`: the suite on `preset` (QUICK_PAPER's M and K grid
    with --quick; CPU_PAPER's data, network and budget with paper-cpu, --steps and --seeds
    still applying), results in <workdir>/paper.json and
    <output_dir>/bench/science_paper.json."""
    from dataclasses import replace

    from bench.science_paper import (
        CPU_PAPER,
        PAPER_HEADLINE,
        QUICK_PAPER,
        PaperSuite,
        run_paper,
    )
    from dags.graph import STAGES
    from pipeline.analysis.figures import save_bench

    suite = (replace(QUICK_PAPER, preset=preset) if quick else
             CPU_PAPER if cpu else PaperSuite(preset))
    if cpu and steps is not None:
        spec = suite.preset.spec
        suite = replace(suite, preset=replace(suite.preset, spec=replace(
            spec, steps=steps, val_every=max(1, min(spec.val_every, steps // 2)))))
    if cpu and seeds is not None:
        suite = replace(suite, preset=replace(suite.preset, seeds=tuple(range(seeds))))
    result = run_paper(suite, (workdir or cfg.layout.science) / "paper", STAGES, cache, jobs,
                       train_missing)
    save_bench(cfg.output_dir, "science_paper", result)
    emit({k: result[k] for k in PAPER_HEADLINE if k in result}, as_json, "bench science paper")


def bench_ddp(
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
