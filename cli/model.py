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
from rich.table import Table

from cli.common import config_of, console, fail, local_output, stdout
from schemas.modes import PACKET_MODES

if TYPE_CHECKING:
    from model.dataset import ClipStream
    from model.evaluate import TargetResult
    from model.train_step import Trainer
    from schemas.config import M3GDConfig


class Prediction(StrEnum):
    """Backbone output parametrizations (model.net.PREDICTIONS)."""

    x = "x"
    v = "v"


class Anchor(StrEnum):
    """What an x-prediction output is added to (model.net.ANCHORS)."""

    nearest_source = "nearest_source"
    none = "none"


Mode = StrEnum("Mode", {m: m for m in PACKET_MODES})  # type: ignore[misc]
"""Packet modes of the paper's ablation (schemas.modes)."""


JsonOpt = Annotated[bool, typer.Option("--json", help="Print JSON.")]
StepsOpt = Annotated[int | None, typer.Option("--steps", help="Euler steps K (config).")]
GuidanceOpt = Annotated[float | None, typer.Option(
    "--guidance", help="Classifier-free guidance scale s (config).")]
AdaptiveOpt = Annotated[float | None, typer.Option(
    "--adaptive", help="Stop when the t=0 extrapolation changes by < TOL (relative).")]
EmaOpt = Annotated[bool, typer.Option(
    "--ema/--raw", help="EMA weights (decay 0.9995: needs thousands of steps) or raw ones.")]
ThreadsOpt = Annotated[int, typer.Option(
    min=1, help="Torch intra-op threads (1 is fastest on a small shared CPU).")]


def _threads(n: int) -> None:
    """Set torch's intra-op thread count."""
    import torch

    torch.set_num_threads(n)


def _checkpoint_meta(path: Path) -> dict[str, Any]:
    """state.json of a checkpoint directory, or exit with one line."""
    state = path / "state.json"
    hint = _train_hint(path)
    if not path.exists():
        fail(f"{path}: no such checkpoint directory; train one with `{hint}`")
    if not state.exists():
        fail(f"{path} holds no checkpoint (no state.json); train one with `{hint}`")
    meta: dict[str, Any] = json.loads(state.read_text())
    return meta


def _train_hint(path: Path) -> str:
    """The `m3gd train` command that writes a checkpoint to `path`, in the packet mode the
    folder is named after (out/train/geom_only: --mode geom_only)."""
    mode = f" --mode {path.name}" if path.name in PACKET_MODES else ""
    return f"m3gd train{mode} --out {path}"


def _stream(cfg: M3GDConfig, split: str, mode: str, seed: int, **kw: Any) -> ClipStream:
    """ClipStream over cfg.output_dir with clean errors for a missing or unusable cache."""
    from model.dataset import ClipStream
    from model.scoring import check_cache, check_mode
    from schemas.object_store import is_url

    try:
        if not is_url(cfg.output_dir):  # on S3 the stream checks the location itself
            check_cache(cfg.output_dir)
        stream = ClipStream(cfg.output_dir, split, mode, seed=seed, **kw)
        if not stream.clips:
            fail(f"{cfg.layout.clips}: no {split!r} clip")
        check_mode(stream)
    except (FileNotFoundError, ValueError) as err:
        fail(str(err))
    return stream


def _train(cfg: M3GDConfig, mode: str | None, steps: int, batch_size: int, preset: str,
           out: Path | None, resume_run: bool, force: bool, every: int, workers: int,
           prediction: str = "x", anchor: str = "none") -> None:
    """Body of `m3gd train` (see the command's help)."""
    from dataclasses import replace

    from model.compare import net_config_from_cache
    from model.loop import resume
    from model.train_step import Trainer
    from schemas.object_store import is_url, parse_url

    if resume_run:
        if out is None:
            out = cfg.layout.train_of(mode or "full")
        meta = _checkpoint_meta(out)
        saved = str(meta["net"]["mode"])
        if mode is not None and mode != saved:
            fail(f"{out} was trained with --mode {saved}, not {mode}")
        mode = saved
        stream = _stream(cfg, "train", mode, int(meta["train"]["seed"]))
        trainer = resume(out, stream)
        stdout.print(f"resumed {out} at step {trainer.step_count} "
                     f"(epoch {stream.state.epoch})", highlight=False, soft_wrap=True)
    else:
        mode = mode or "full"
        if out is None and is_url(cfg.output_dir):
            fail(f"{parse_url(cfg.output_dir)}: checkpoints are not written to object storage "
                 "yet; "
                 "pass --out DIR")
        out = out or cfg.layout.train_of(mode)
        if (out / "state.json").exists() and not force:
            fail(f"{out} already holds a checkpoint; --resume to continue it or --force to "
                 "start over")
        stream = _stream(cfg, "train", mode, cfg.train.seed)
        try:
            net_cfg = replace(net_config_from_cache(stream, mode, preset), prediction=prediction,
                              anchor=anchor, patch=cfg.train.patch)
            trainer = Trainer(net_cfg, _optimization(cfg, steps))
        except ValueError as err:
            fail(str(err))
    if trainer.step_count >= steps:
        stdout.print(f"{out} is already at step {trainer.step_count} >= --steps {steps}",
                     highlight=False, soft_wrap=True)
        return
    _run_training(trainer, stream, steps, batch_size, out, every, workers)


def _optimization(cfg: M3GDConfig, steps: int) -> Any:
    """The trainer's TrainConfig from `train` (warm-up, then cosine decay to lr_min over the
    rest of `steps`: the science bench's schedule)."""
    from model.train_step import TrainConfig

    t = cfg.train
    return TrainConfig(lr=t.lr, bf16=t.bf16, seed=t.seed, warmup_steps=t.warmup_steps,
                       decay_steps=max(0, steps - t.warmup_steps), lr_min=t.lr_min,
                       ema_decay=t.ema_decay)


def _run_training(trainer: Trainer, stream: ClipStream, steps: int, batch_size: int, out: Path,
                  every: int, workers: int) -> None:
    """Train with a rich progress bar and periodic loss lines; print where the checkpoint is."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn

    from model.loop import train_loop
    from pipeline.run.progress import make_progress

    start = trainer.step_count
    report = max(1, (steps - start) // 10)
    window: list[float] = []
    with make_progress(TextColumn("train"), BarColumn(), MofNCompleteColumn(),
                       TextColumn("loss {task.fields[loss]}"), console=console,
                       transient=True) as bar:
        task = bar.add_task("train", total=steps, completed=start, loss="-")

        def on_step(step: int, loss: float) -> None:
            window.append(loss)
            bar.update(task, completed=step, loss=f"{loss:.4f}")
            if (step - start) % report == 0 or step == steps:
                mean = sum(window) / len(window)
                stdout.print(f"step {step:>6}/{steps}  loss {mean:.4f} "
                             f"(mean of {len(window)})", highlight=False, soft_wrap=True)
                window.clear()

        try:
            losses = train_loop(trainer, stream, steps, batch_size, out, every, workers,
                                on_step)
        except (ValueError, FloatingPointError) as err:
            fail(str(err))
    tail = losses[-min(len(losses), 20):]
    stdout.print(f"checkpoint: {out} (step {trainer.step_count}, mode {stream.mode}, "
                 f"loss {sum(tail) / len(tail):.4f} over the last {len(tail)} steps)",
                 highlight=False, soft_wrap=True)


def _score(cfg: M3GDConfig, checkpoint: Path, clips: int | None, steps: int | None,
           guidance: float | None, tol: float | None, ema: bool, batch_size: int | None,
           on_batch: Any = None) -> tuple[list[TargetResult], ClipStream, dict[str, Any]]:
    """Sample and score eval clips with a checkpoint; returns results, stream and settings."""
    from model.scoring import image_decoder, load_net, score_clips

    meta = _checkpoint_meta(checkpoint)
    mode = str(meta["net"]["mode"])
    stream = _stream(cfg, "eval", mode, cfg.train.seed, shuffle=False, with_images=True)
    try:
        decoder = image_decoder(stream, cfg.encoders.seed)
        net, trainer = load_net(checkpoint, ema)
    except ValueError as err:
        fail(str(err))
    k = steps or cfg.sample.steps
    s = cfg.sample.guidance if guidance is None else guidance
    tol = cfg.sample.adaptive_tol if tol is None else tol
    results = score_clips(net, stream, decoder, clips, batch_size or cfg.train.batch_size, k, s,
                          tol, cfg.train.seed, on_batch)
    settings = {"checkpoint": str(checkpoint), "mode": mode, "train_step": trainer.step_count,
                "weights": "ema" if ema else "raw", "steps": k, "guidance": s,
                "adaptive_tol": tol}
    return results, stream, settings


def _score_command(ctx: typer.Context, checkpoint: Path | None, clips: int | None,
                   steps: int | None, guidance: float | None, tol: float | None, ema: bool,
                   batch_size: int | None, threads: int
                   ) -> tuple[M3GDConfig, Path, list[TargetResult], ClipStream, dict[str, Any]]:
    """What `sample` and `eval` share: config, threads, checkpoint (default), scored clips."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn

    from pipeline.run.progress import make_progress

    cfg = config_of(ctx)
    _threads(threads)
    ckpt = _default_checkpoint(cfg, checkpoint)
    _checkpoint_meta(ckpt)  # a missing checkpoint: its one line before any progress
    with make_progress(TextColumn("score"), BarColumn(), MofNCompleteColumn(),
                       TextColumn("clips"), console=console, transient=True) as bar:
        task = bar.add_task("score clips", total=clips)
        results, stream, settings = _score(cfg, ckpt, clips, steps, guidance, tol, ema,
                                           batch_size, lambda n: bar.advance(task, n))
        scored = len(stream.clips) if clips is None else min(clips, len(stream.clips))
        bar.update(task, total=scored)  # fewer eval clips than asked: the count scored
    return cfg, ckpt, results, stream, settings


def _target_table(results: list[TargetResult], ordinals: list[int]) -> Table:
    """Per-target scores: clip, target ordinal, view, PSNR, SSIM, and the baselines' PSNR."""
    table = Table(title="target views")
    for col in ("clip", "target", "view", "PSNR dB", "SSIM", "copy-source dB", "mean-latent dB"):
        table.add_column(col, justify="right")
    for r, k in zip(results, ordinals, strict=True):
        base = [f"{r.baselines[n][0]:.2f}" if n in r.baselines else "-"
                for n in ("copy_source", "mean_latent")]
        table.add_row(str(r.clip_id), str(k), str(r.view), f"{r.psnr:.2f}", f"{r.ssim:.3f}",
                      *base)
    return table


def _margin_line(summary: dict[str, Any]) -> str:
    """The model against both baselines on the same targets, one line."""
    if "baselines" not in summary:
        return "no baseline (the clips carry no camera poses)"
    b = summary["baselines"]
    return (f"model {summary['psnr_mean']:.2f} dB / SSIM {summary['ssim_mean']:.3f}; "
            f"copy-nearest-source {b['copy_source']['psnr_mean']:.2f} / "
            f"{b['copy_source']['ssim_mean']:.3f}; mean latent "
            f"{b['mean_latent']['psnr_mean']:.2f} / {b['mean_latent']['ssim_mean']:.3f}; "
            f"margin over the better baseline ({summary['better_baseline']}) "
            f"{summary['margin_db']:+.2f} dB")


def _recipe_hint(summary: dict[str, Any], train_step: int) -> str | None:
    """A line for a model below the better baseline: what a working recipe is."""
    margin = summary.get("margin_db")
    if margin is None or margin >= 0:
        return None
    from schemas.config import TrainConfig

    steps = TrainConfig().steps
    return (f"below the {summary['better_baseline']} baseline after {train_step} training "
            f"steps: `m3gd train`'s defaults are the recipe measured to beat both baselines "
            f"({steps} steps; docs/guides/trainers.md, 'The training recipe')")


def _ordinals(results: list[TargetResult]) -> list[int]:
    """Index of each result among the targets of its clip (0, 1, ...)."""
    count: dict[int, int] = {}
    out = []
    for r in results:
        out.append(count.get(r.clip_id, 0))
        count[r.clip_id] = out[-1] + 1
    return out


def _write_samples(results: list[TargetResult], out: Path) -> Path:
    """PNG pairs <out>/samples/<clip_id>/target_<k>_{pred,gt}.png; returns the samples dir."""
    from PIL import Image

    root = out / "samples"
    for r, k in zip(results, _ordinals(results), strict=True):
        where = root / str(r.clip_id)
        where.mkdir(parents=True, exist_ok=True)
        Image.fromarray(r.pred).save(where / f"target_{k}_pred.png")
        Image.fromarray(r.gt).save(where / f"target_{k}_gt.png")
    return root


def _summary_table(summary: dict[str, Any]) -> Table:
    """Mean scores overall and per hard / other subset."""
    table = Table(title="eval")
    for col in ("subset", "targets", "PSNR dB mean", "PSNR dB median", "SSIM mean"):
        table.add_column(col, justify="left" if col == "subset" else "right")
    for name, row in [("all", summary), ("hard", summary.get("hard")),
                      ("not hard", summary.get("not_hard"))]:
        if row is not None:
            table.add_row(name, str(row["targets"]), f"{row['psnr_mean']:.2f}",
                          f"{row['psnr_median']:.2f}", f"{row['ssim_mean']:.3f}")
    return table


def _default_checkpoint(cfg: M3GDConfig, checkpoint: Path | None) -> Path:
    """The given checkpoint or <output_dir>/train/full."""
    return checkpoint if checkpoint is not None else cfg.layout.train_of("full")


def train(
    ctx: typer.Context,
    mode: Annotated[Mode | None, typer.Option(help="Packet mode (default full).")] = None,
    steps: Annotated[int | None, typer.Option(
        min=1, help="Train until this step count (train.steps).")] = None,
    batch_size: Annotated[int | None, typer.Option(min=1, help="train.batch_size")] = None,
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
        min=0, help="DataLoader workers (train.loader_workers).")] = None,
    threads: ThreadsOpt = 1,
    prediction: Annotated[Prediction, typer.Option(
        help="Backbone output: x (clean latent, default) or v (the paper's velocity).")
                          ] = Prediction.x,
    anchor: Annotated[Anchor, typer.Option(
        help="x-prediction only: z0_hat = anchor + output, with nearest_source the latent of "
             "the source view nearest the target (an untrained net copies it).")
                      ] = Anchor.none,
) -> None:
    """Train M3GD on the cache's training clips; save a safetensors + JSON checkpoint.

    The defaults (config section `train`) are the recipe the science bench measured (`m3gd
    bench science`, preset FULL): x-prediction, AdamW lr 1e-3 with 50 warm-up steps and cosine
    decay to 1e-5, 8000 steps of 8 clips, EMA 0.998, preset tiny at patch 1.
    """
    cfg = config_of(ctx)
    _threads(threads)
    t = cfg.train
    _train(cfg, mode.value if mode is not None else None, steps or t.steps,
           batch_size or t.batch_size, preset or t.preset, out, resume, force, every,
           t.loader_workers if workers is None else workers, prediction.value,
           anchor.value)


def sample(
    ctx: typer.Context,
    checkpoint: Annotated[Path | None, typer.Argument(
        help="Checkpoint directory (<output_dir>/train/full).")] = None,
    steps: StepsOpt = None, guidance: GuidanceOpt = None, adaptive: AdaptiveOpt = None,
    clips: Annotated[int, typer.Option(min=1, help="Eval clips to synthesize.")] = 4,
    out: Annotated[Path | None, typer.Option(
        help="Folder for samples/<clip_id>/ (output_dir).")] = None,
    ema: EmaOpt = False,
    batch_size: Annotated[int | None, typer.Option(min=1)] = None,
    threads: ThreadsOpt = 1,
) -> None:
    """Synthesize eval-split target views; write PNGs beside the ground truth; score."""
    from model.scoring import summarize

    local_output(config_of(ctx).output_dir, "sample", "CHECKPOINT and --out DIR",
                 checkpoint is not None and out is not None)
    cfg, _, results, stream, settings = _score_command(
        ctx, checkpoint, clips, steps, guidance, adaptive, ema, batch_size, threads)
    where = _write_samples(results, out or cfg.output_dir)
    stdout.print(_target_table(results, _ordinals(results)))
    summary = summarize(results, stream)
    stdout.print(_margin_line(summary), highlight=False, soft_wrap=True)
    hint = _recipe_hint(summary, settings["train_step"])
    if hint is not None:
        stdout.print(hint, highlight=False, soft_wrap=True)
    stdout.print(f"K={settings['steps']} s={settings['guidance']} "
                 f"weights={settings['weights']} step={settings['train_step']}; "
                 f"{len(results)} targets written to {where}", highlight=False, soft_wrap=True)


def evaluate(
    ctx: typer.Context,
    checkpoint: Annotated[Path | None, typer.Argument(
        help="Checkpoint directory (<output_dir>/train/full).")] = None,
    steps: StepsOpt = None, guidance: GuidanceOpt = None, adaptive: AdaptiveOpt = None,
    clips: Annotated[int, typer.Option(
        min=1, help="Eval clips (the first N, fixed order; minutes, not a quarter hour).")] = 32,
    result: Annotated[Path | None, typer.Option(
        help="Result JSON (<checkpoint>/eval.json); per-target Parquet beside it.")] = None,
    ema: EmaOpt = False,
    batch_size: Annotated[int | None, typer.Option(min=1)] = None,
    as_json: JsonOpt = False,
    threads: ThreadsOpt = 1,
) -> None:
    """Mean target-view PSNR/SSIM over eval clips (hard subset apart); write the result."""
    from model.scoring import summarize, target_rows
    from pipeline.analysis.model_eval import write_eval

    local_output(config_of(ctx).output_dir, "eval", "CHECKPOINT", checkpoint is not None)
    _, ckpt, results, stream, settings = _score_command(
        ctx, checkpoint, clips, steps, guidance, adaptive, ema, batch_size, threads)
    try:
        summary = {**settings, **summarize(results, stream)}
    except ValueError as err:
        fail(str(err))
    path = write_eval(summary, target_rows(results, stream), result or ckpt / "eval.json")
    if as_json:
        stdout.print_json(json.dumps(summary))
        return
    stdout.print(_summary_table(summary))
    stdout.print(_margin_line(summary), highlight=False, soft_wrap=True)
    hint = _recipe_hint(summary, settings["train_step"])
    if hint is not None:
        stdout.print(hint, highlight=False, soft_wrap=True)
    stdout.print(f"{summary['clips']} clips, K={summary['steps']} s={summary['guidance']}"
                 f" weights={summary['weights']}; written: {path}", highlight=False,
                 soft_wrap=True)


def bench_sampler(
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
) -> None:
    """Latency, latency per target and peak memory against K and M (paper Table 7)."""
    _threads(threads)
    cfg = config_of(ctx)
    local_output(cfg.output_dir, "bench sampler")
    result = _sampler_bench(cfg, quick, checkpoint, clips, repeats, ema)
    from pipeline.analysis.figures import save_bench

    save_bench(cfg.output_dir, "sampler", result)  # `m3gd plot` draws its speed-accuracy
    if as_json:
        stdout.print_json(json.dumps(result, default=str))
        return
    _print_sampler(result)


def _sampler_bench(cfg: M3GDConfig, quick: bool, checkpoint: Path | None, clips: int,
                   repeats: int | None, ema: bool) -> dict[str, Any]:
    """run_sampler_bench on the full or quick grid; PSNR/SSIM against K with a checkpoint.

    Every figure uses the `ema` choice of a checkpoint's weights (raw by default, as
    `m3gd eval` does: EMA 0.9995 barely moves in a short run).
    """
    from dataclasses import replace

    from bench.sampler_bench import SamplerBenchSpec, run_sampler_bench

    spec = SamplerBenchSpec()
    if quick:
        spec = replace(spec, steps=(1, 2), targets=(2,), c=16, c_u=8, grid_hw=(4, 6),
                       image_hw=(56, 84), repeats=1, reference_steps=4)
    if checkpoint is not None:
        net = _checkpoint_meta(checkpoint)["net"]
        spec = replace(spec, c=int(net["c"]), c_u=int(net["c_u"]),
                       grid_hw=tuple(net["grid_hw"]), image_hw=tuple(net["image_hw"]),
                       preset=str(net["preset"]))
    if repeats is not None:
        spec = replace(spec, repeats=repeats)
    result = run_sampler_bench(spec, checkpoint, ema)
    if checkpoint is not None:
        from model.scoring import summarize

        quality: dict[str, Any] = {}
        for k in spec.steps:
            res, stream, _ = _score(cfg, checkpoint, clips, k, spec.guidance, None, ema, None)
            quality[str(k)] = summarize(res, stream)
        result["quality_psnr_ssim"] = quality
        result["quality_psnr_ssim_weights"] = "ema" if ema else "raw"
    return result


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
