"""Model commands of the `m3gd` CLI: train, sample, eval, bench sampler, bench loader.

All of them read the cache and clip index at the configured output_dir. Checkpoints are
directories of safetensors + JSON (`model.checkpoint`); `train` writes them to
<output_dir>/train/<mode> unless told otherwise.
"""

from __future__ import annotations

import json
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from cli.common import (
    check_threads,
    checkpoint_folder,
    config_of,
    console,
    fail,
    local_output,
    refuse_foreign_output,
    stdout,
    write_json,
)
from cli.model_lines import (
    margin_line,
    ordinals,
    recipe_hint,
    sampler_lines,
    score_lines,
    summary_table,
    target_table,
    write_samples,
)
from schemas.modes import MODEL_MODES

if TYPE_CHECKING:

    import torch

    from model.dataset import ClipStream
    from model.evaluate import TargetResult
    from model.runs import LoopSettings, ScoreRequest, TrainRequest
    from schemas.config import M3GDConfig


class Prediction(StrEnum):
    """Backbone output parametrizations (model.net.PREDICTIONS)."""

    x = "x"
    v = "v"


class LossSpace(StrEnum):
    """What the training loss scores (model.train_step.TrainConfig.loss_space)."""

    v = "v"
    x = "x"


class Anchor(StrEnum):
    """What an x-prediction output is added to (model.net.ANCHORS)."""

    nearest_source = "nearest_source"
    reprojection = "reprojection"
    none = "none"


TrainingMode = StrEnum("TrainingMode", {m: m for m in ("scratch", "freeze", "finetune")})  # type: ignore[misc]
"""How a run starts and what it trains (model.training_modes.TRAINING_MODES)."""
LossViews = StrEnum("LossViews", {m: m for m in ("target", "all")})  # type: ignore[misc]
"""Views the loss scores (model.training_modes.LOSS_VIEWS)."""
SCRATCH, TARGET_VIEWS = TrainingMode("scratch"), LossViews("target")
"""The defaults of `train --training-mode` and `--loss-views`."""
Mode = StrEnum("Mode", {m: m for m in MODEL_MODES})  # type: ignore[misc]
"""Packet modes of the paper's ablation (schemas.modes)."""


JsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON.")]
StepsOpt = Annotated[int | None, typer.Option("--steps", help="Euler steps K (config).")]
GuidanceOpt = Annotated[float | None, typer.Option(
    "--guidance", help="Classifier-free guidance scale s (config).")]
TemperatureOpt = Annotated[float | None, typer.Option(
    "--temperature", min=0, help="Start-noise scale (config; 1: the paper's draw, 0: "
    "deterministic, the most accurate in PSNR).")]
AdaptiveOpt = Annotated[float | None, typer.Option(
    "--adaptive", help="Stop when the t=0 extrapolation changes by < TOL (relative).")]
EmaOpt = Annotated[bool, typer.Option(
    "--ema/--raw", help="EMA weights (decay 0.9995: needs thousands of steps) or raw ones.")]
ThreadsOpt = Annotated[int, typer.Option(
    min=1, help="Torch intra-op threads (1 is fastest on a small shared CPU).")]


DeviceOpt = Annotated[str | None, typer.Option(
    "--device", help="auto | cpu | cuda | cuda:N | mps (train.device; auto: CUDA when "
                     "available).")]


def _threads(n: int) -> None:
    """Set torch's intra-op thread count (at most `cli.common.max_threads`)."""
    import torch

    check_threads(n)
    torch.set_num_threads(n)


def _device(cfg: M3GDConfig, option: str | None) -> torch.device:
    """The device of this process (--device, else train.device; under torchrun a bare cuda
    is this rank's GPU), or exit with one line."""
    from model.distributed import device_of, from_env
    from schemas.errors import DataError

    try:
        return device_of(option or cfg.train.device, from_env())
    except DataError as err:
        fail(str(err), 2)


class _Progress:
    """The training progress line: step, loss, steps/s and ETA; a live line on a terminal,
    plain lines (every tenth of the run) when the output is a file or a pipe."""

    def __init__(self, start: int, steps: int) -> None:
        self.start, self.steps = start, steps
        self.every = max(1, (steps - start) // 10)
        self.window: list[float] = []
        self.live = console.is_terminal

    def __call__(self, step: int, loss: float, rate: float) -> None:
        self.window.append(loss)
        eta = (self.steps - step) / rate if rate > 0 else float("nan")
        line = (f"step {step:>6}/{self.steps}  loss {sum(self.window) / len(self.window):.4f}"
                f"  {rate:.2f} steps/s  ETA {_clock(eta)}")
        if self.live:
            console.print(line, end="\r", highlight=False, soft_wrap=True)
        if (step - self.start) % self.every == 0 or step == self.steps:
            if self.live:
                console.print(" " * len(line), end="\r")
            stdout.print(line, highlight=False, soft_wrap=True)
            self.window.clear()


def _clock(seconds: float) -> str:
    """h:mm:ss of a duration ("-" when unknown)."""
    if seconds != seconds or seconds == float("inf"):
        return "-"
    s = round(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def _train(cfg: M3GDConfig, req: TrainRequest, loop: LoopSettings,
           device_opt: str | None) -> None:
    """Body of `m3gd train` (see the command's help)."""
    from model import distributed
    from model.runs import run_training, start_training
    from schemas.errors import DataError
    from store.object_store import is_url

    if not req.resume and not (req.out is None and is_url(cfg.output_dir)):
        out = req.out or cfg.layout.train_of(req.mode or "full")
        refuse_foreign_output(out, cfg, "checkpoint", checkpoint_folder)
    dist = distributed.from_env()
    device = _device(cfg, device_opt)
    try:
        distributed.init(dist, device)
        setup = start_training(cfg, req, device, dist)
    except DataError as err:
        fail(str(err))
    tr = setup.trainer
    say = stdout.print if dist.is_main else (lambda *a, **k: None)
    for note in setup.notes:
        say(note, highlight=False, soft_wrap=True)
    if setup.resumed:
        pos = tr.extra.get("stream", {})
        say(f"resumed {setup.out} at step {tr.step_count} (epoch {pos.get('epoch', 0)})",
            highlight=False, soft_wrap=True)
    if tr.step_count >= loop.steps:
        say(f"{setup.out} is already at step {tr.step_count} >= --steps {loop.steps}",
            highlight=False, soft_wrap=True)
        return
    say(f"training on {device} ({tr.precision}), {dist.world_size} rank(s); global batch "
        f"{loop.batch_size} x {dist.world_size} x {tr.cfg.grad_accum}", highlight=False,
        soft_wrap=True)
    progress = _Progress(tr.step_count, loop.steps) if dist.is_main else None
    try:
        losses = run_training(cfg, setup, loop, progress,
                              score_lines(loop, say) if dist.is_main else None)
    except (ValueError, FloatingPointError) as err:
        fail(str(err))
    except OSError as err:  # a full disk, a folder made read-only while training
        fail(f"{err.filename or setup.out}: {err.strerror or err}; nothing after the last "
             "checkpoint was saved")
    finally:
        distributed.shutdown()
    tail = losses[-min(len(losses), 20):]
    say(f"checkpoint: {setup.out} (step {tr.step_count}, mode {setup.stream.mode}, "
        f"loss {sum(tail) / len(tail):.4f} over the last {len(tail)} steps); metrics: "
        f"{setup.out / 'metrics.jsonl'}", highlight=False, soft_wrap=True)
    for line in sampler_lines(setup):
        say(line, highlight=False, soft_wrap=True)


def _score_command(ctx: typer.Context, checkpoint: Path | None, req: ScoreRequest,
                   threads: int, device_opt: str | None
                   ) -> tuple[M3GDConfig, Path, list[TargetResult], ClipStream, dict[str, Any]]:
    """What `sample` and `eval` share: config, threads, checkpoint (default), scored clips."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn

    from model.runs import checkpoint_meta, score_checkpoint
    from pipeline.run.progress import make_progress
    from schemas.errors import DataError

    cfg = config_of(ctx)
    _threads(threads)
    ckpt = _default_checkpoint(cfg, checkpoint)
    device = _device(cfg, device_opt)
    try:
        checkpoint_meta(ckpt)  # a missing checkpoint: its one line before any progress
    except DataError as err:
        fail(str(err))
    with make_progress(TextColumn("score"), BarColumn(), MofNCompleteColumn(),
                       TextColumn("clips"), console=console, transient=True) as bar:
        task = bar.add_task("score clips", total=req.clips)
        try:
            results, stream, settings = score_checkpoint(
                cfg, ckpt, req, device, lambda n: bar.advance(task, n))
        except DataError as err:
            fail(str(err))
        scored = len(stream.clips) if req.clips is None else min(req.clips, len(stream.clips))
        bar.update(task, total=scored)  # fewer eval clips than asked: the count scored
    console.print(f"temperature {settings['temperature']:g}: {settings['temperature_from']}",
                  highlight=False, soft_wrap=True)
    if "temperature_note" in settings:
        console.print(f"note: {settings['temperature_note']}", highlight=False, soft_wrap=True)
    return cfg, ckpt, results, stream, settings


def _default_checkpoint(cfg: M3GDConfig, checkpoint: Path | None) -> Path:
    """The given checkpoint or <output_dir>/train/full."""
    return checkpoint if checkpoint is not None else cfg.layout.train_of("full")


def _eval_output(path: Path) -> bool:
    """Whether `path` is a file `m3gd eval` wrote: its result JSON (an object with the
    scoring settings) or the per-target Parquet beside it."""
    if not path.is_file():
        return False
    if path.suffix == ".parquet":
        return path.with_suffix(".json").is_file() and _eval_output(path.with_suffix(".json"))
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and {"clips", "steps", "weights"} <= data.keys()


def train(
    ctx: typer.Context,
    mode: Annotated[Mode | None, typer.Option(help="Packet mode (default full).")] = None,
    steps: Annotated[int | None, typer.Option(
        min=1, help="Train until this step count (train.steps).")] = None,
    batch_size: Annotated[int | None, typer.Option(
        min=1, help="Clips per rank and micro-batch (train.batch_size).")] = None,
    preset: Annotated[str | None, typer.Option(help="Network preset (train.preset).")
                      ] = None,
    out: Annotated[Path | None, typer.Option(
        help="Checkpoint directory (<output_dir>/train/<mode>).")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue the checkpoint in --out mid-epoch.")] = False,
    force: Annotated[bool, typer.Option(
        "--force", help="Start over even if --out holds a checkpoint.")] = False,
    every: Annotated[int, typer.Option(
        min=0, help="Also checkpoint every N steps (0: only at the end).")] = 0,
    workers: Annotated[int | None, typer.Option(
        min=0, help="DataLoader workers per rank (train.loader_workers).")] = None,
    threads: ThreadsOpt = 1,
    prediction: Annotated[Prediction, typer.Option(
        help="Backbone output: x (clean latent, default) or v (the paper's velocity).")
                          ] = Prediction.x,
    anchor: Annotated[Anchor, typer.Option(
        help="x-prediction only: z0_hat = anchor + output, with nearest_source the latent of "
             "the source view nearest the target (an untrained net copies it), reprojection "
             "its LiDAR reprojection (warp modes; the nearest source where no source sees).")
                      ] = Anchor.none,
    device: DeviceOpt = None,
    compile_net: Annotated[bool | None, typer.Option(
        "--compile/--no-compile", help="torch.compile the backbone (train.compile).")] = None,
    training_mode: Annotated[TrainingMode, typer.Option(
        help="scratch; freeze (start from --init-from, train only the adapter); finetune "
             "(start from --init-from, train all).")] = SCRATCH,
    init_from: Annotated[Path | None, typer.Option(
        help="The no_lidar checkpoint a freeze or finetune run starts from.")] = None,
    loss_views: Annotated[LossViews, typer.Option(
        help="Views the loss scores: target (the paper's eq. 12) or all.")] = TARGET_VIEWS,
    lidar_dropout: Annotated[bool, typer.Option(
        "--lidar-dropout/--no-lidar-dropout",
        help="Classifier-free LiDAR dropout (null packet in 10 % of clips).")] = True,
    loss_space: Annotated[LossSpace, typer.Option(
        help="What the loss scores: v (the velocity, eq. 12) or x (the clean latent: t^2 times "
             "eq. 12's terms; better at K = 1 on the paper-cpu suite, "
             "docs/benchmarks_model.md).")] = LossSpace.v,
    val_recordings: Annotated[int, typer.Option(
        min=0, help="Training recordings held out of training to choose the sampler's "
                    "temperature after it (K = sample.steps), recorded in the checkpoint as "
                    "sample's and eval's default; 0: none (they sample at 1, the paper's).")
                          ] = 0,
) -> None:
    """Train M3GD on the cache's training clips; save a safetensors checkpoint.

    The defaults (config section `train`) are the recipe the science bench measured (`m3gd
    bench science`, preset FULL): x-prediction, AdamW lr 1e-3 with 50 warm-up steps and cosine
    decay to 1e-5 at the last step, 8000 steps of 8 clips, EMA 0.998, preset tiny at patch 1.

    Several GPUs or machines: start it with torchrun (docs/training_gpus.md), e.g.
    `torchrun --nproc-per-node 4 -m cli train`; every rank reads its share of each update.
    """
    from model.runs import LoopSettings, TrainRequest
    from model.training_modes import TrainingRegime

    cfg = config_of(ctx)
    if steps is not None:  # the learning-rate schedule ends at the steps of this run
        cfg = cfg.model_copy(update={"train": cfg.train.model_copy(update={"steps": steps})})
    _threads(threads)
    t = cfg.train
    regime = TrainingRegime(training_mode.value, init_from, loss_views.value, lidar_dropout,
                            loss_space.value)
    req = TrainRequest(mode.value if mode is not None else None, preset or t.preset, out,
                       resume, force, prediction.value, anchor.value,
                       t.compile if compile_net is None else compile_net, regime,
                       val_recordings)
    loop = LoopSettings(steps or t.steps, batch_size or t.batch_size, every,
                        t.loader_workers if workers is None else workers, t.log_every,
                        t.eval_every, sample_steps=cfg.sample.steps,
                        guidance=cfg.sample.guidance)
    _train(cfg, req, loop, device)


def sample(
    ctx: typer.Context,
    checkpoint: Annotated[Path | None, typer.Argument(
        help="Checkpoint directory (<output_dir>/train/full).")] = None,
    steps: StepsOpt = None, guidance: GuidanceOpt = None, adaptive: AdaptiveOpt = None,
    temperature: TemperatureOpt = None,
    clips: Annotated[int, typer.Option(min=1, help="Eval clips to synthesize.")] = 4,
    out: Annotated[Path | None, typer.Option(
        help="Folder for samples/<clip_id>/ (output_dir).")] = None,
    ema: EmaOpt = False,
    batch_size: Annotated[int | None, typer.Option(min=1)] = None,
    threads: ThreadsOpt = 1,
    device: DeviceOpt = None,
) -> None:
    """Synthesize eval-split target views; write PNGs beside the ground truth; score."""
    from model.runs import ScoreRequest
    from model.scoring import summarize

    local_output(config_of(ctx).output_dir, "sample", "CHECKPOINT and --out DIR",
                 checkpoint is not None and out is not None)
    req = ScoreRequest(clips, steps, guidance, adaptive, ema, batch_size,
                       temperature=temperature)
    cfg, _, results, stream, settings = _score_command(ctx, checkpoint, req, threads, device)
    where = write_samples(results, out or cfg.output_dir)
    stdout.print(target_table(results, ordinals(results)))
    summary = summarize(results, stream)
    stdout.print(margin_line(summary), highlight=False, soft_wrap=True)
    hint = recipe_hint(summary, settings)
    if hint is not None:
        stdout.print(hint, highlight=False, soft_wrap=True)
    stdout.print(f"K={settings['steps']} s={settings['guidance']} T={settings['temperature']} "
                 f"weights={settings['weights']} step={settings['train_step']}; "
                 f"{len(results)} targets written to {where}", highlight=False, soft_wrap=True)


def evaluate(
    ctx: typer.Context,
    checkpoint: Annotated[Path | None, typer.Argument(
        help="Checkpoint directory (<output_dir>/train/full).")] = None,
    steps: StepsOpt = None, guidance: GuidanceOpt = None, adaptive: AdaptiveOpt = None,
    temperature: TemperatureOpt = None,
    clips: Annotated[int, typer.Option(
        min=1, help="Eval clips (the first N, fixed order; minutes, not a quarter hour).")] = 32,
    result: Annotated[Path | None, typer.Option(
        help="Result JSON (<checkpoint>/eval.json); per-target Parquet beside it.")] = None,
    ema: EmaOpt = False,
    batch_size: Annotated[int | None, typer.Option(min=1)] = None,
    as_json: JsonOpt = False,
    threads: ThreadsOpt = 1,
    device: DeviceOpt = None,
) -> None:
    """Mean target-view PSNR/SSIM over eval clips (hard subset apart); write the result."""
    from model.runs import ScoreRequest
    from model.scoring import summarize, target_rows
    from pipeline.analysis.model_eval import write_eval

    cfg = config_of(ctx)
    local_output(cfg.output_dir, "eval", "CHECKPOINT", checkpoint is not None)
    target = result or _default_checkpoint(cfg, checkpoint) / "eval.json"
    for written in (target, target.with_suffix(".parquet")):  # refused before any scoring
        refuse_foreign_output(written, cfg, "eval result", _eval_output)
    req = ScoreRequest(clips, steps, guidance, adaptive, ema, batch_size, keep_images=False,
                       temperature=temperature)
    _, _, results, stream, settings = _score_command(ctx, checkpoint, req, threads, device)
    try:
        summary = {**settings, **summarize(results, stream)}
    except ValueError as err:
        fail(str(err))
    try:
        path = write_eval(summary, target_rows(results, stream), target)
    except OSError as err:  # a full disk, a read-only folder
        fail(f"{err.filename or target}: {err.strerror or err}; the eval result was not written")
    if as_json:
        write_json(summary)
        return
    stdout.print(summary_table(summary))
    stdout.print(margin_line(summary), highlight=False, soft_wrap=True)
    hint = recipe_hint(summary, settings)
    if hint is not None:
        stdout.print(hint, highlight=False, soft_wrap=True)
    stdout.print(f"{summary['clips']} clips, K={summary['steps']} s={summary['guidance']}"
                 f" T={summary['temperature']} weights={summary['weights']}; written: {path}",
                 highlight=False, soft_wrap=True)
