"""Model runs from the configuration: training (new or resumed) and scoring a checkpoint.

The policy behind `m3gd train`, `m3gd sample` and `m3gd eval` (the commands only parse
options and call `start_training`, `run_training`, `score_checkpoint`): a new run refuses to
overwrite a checkpoint unless forced; a resumed run keeps the packet mode and seed it was
trained with, and `--resume` of a run stopped before its first save starts it over (saying
so); the temporaries of killed saves are removed when a run starts, and an output folder
that cannot be written is refused before any work; the device and ranks come from the
configuration and torchrun's environment. A run with validation recordings
(`TrainRequest.val_recordings`) trains without them and, after the last update, records in
the checkpoint the sampler temperature they choose; sample and eval use it by default
(`model.temperature`); `--resume` holds out the ones the run recorded (`write_run`).
Every refusal is a `DataError` with one line.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from model.checkpoint import (
    has_checkpoint,
    read_meta,
    read_run,
    remove_temporaries,
    temporaries,
    write_run,
)
from model.clips import no_clip_message
from model.compare import net_config_from_cache
from model.dataset import ClipStream
from model.distributed import DistInfo
from model.encoders.base import ImageDecoder
from model.evaluate import TargetResult
from model.loop import LoopOptions, train_loop
from model.net import M3GDNet
from model.sampler import check_temperature
from model.scoring import (
    check_cache,
    check_mode,
    held_out_scores,
    image_decoder,
    load_net,
    score_clips,
)
from model.temperature import (
    Choice,
    choose_temperature,
    hold_out,
    record_sampler,
    resolve_temperature,
    val_recordings,
)
from model.train_log import FILENAME, TrainLog
from model.train_step import TrainConfig, Trainer
from model.training_modes import TrainingRegime, start_from
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.modes import MODEL_MODES
from store.object_store import is_url, parse_url


def open_stream(cfg: M3GDConfig, split: str, mode: str, seed: int, **kw: Any) -> ClipStream:
    """ClipStream of `split` over cfg.output_dir; one-line errors for a missing or unusable
    cache (no clip of the split, a packet mode the cache does not hold)."""
    try:
        if not is_url(cfg.output_dir):  # on S3 the stream checks the location itself
            check_cache(cfg.output_dir)
        stream = ClipStream(cfg.output_dir, split, mode, seed=seed, **kw)
        if not stream.clips:
            raise DataError(no_clip_message(cfg.layout.clips, split))
        check_mode(stream)
    except (FileNotFoundError, ValueError) as err:
        raise DataError(str(err)) from err
    return stream


def checkpoint_meta(path: Path) -> dict[str, Any]:
    """The state of the checkpoint in directory `path`, or a one-line DataError."""
    if not path.exists():
        raise DataError(f"{path}: no such checkpoint directory; train one with "
                        f"`{train_hint(path)}`")
    if not has_checkpoint(path):
        raise DataError(f"{path} holds no checkpoint; train one with `{train_hint(path)}`")
    return read_meta(path)


def train_hint(path: Path) -> str:
    """The `m3gd train` command that writes a checkpoint to `path`, in the packet mode the
    folder is named after (out/train/geom_only: --mode geom_only)."""
    mode = f" --mode {path.name}" if path.name in MODEL_MODES else ""
    return f"m3gd train{mode} --out {path}"


@dataclass(frozen=True)
class TrainRequest:
    """What `m3gd train` was asked for (None: from the configuration or the checkpoint)."""

    mode: str | None = None
    preset: str = "tiny"
    out: Path | None = None
    resume: bool = False
    force: bool = False
    prediction: str = "x"
    anchor: str = "none"
    compile: bool = False
    regime: TrainingRegime = field(default_factory=TrainingRegime)  # mode, loss views, dropout
    val_recordings: int = 0
    """Training recordings held out to choose the sampler's temperature (0: none)."""


@dataclass
class TrainSetup:
    """A trainer ready to run, its stream, checkpoint directory and whether it was resumed."""

    trainer: Trainer
    stream: ClipStream
    out: Path
    resumed: bool
    notes: list[str] = field(default_factory=list)
    """What the user should be told before training (a restart, temporaries removed)."""
    val: list[str] = field(default_factory=list)
    """The validation recordings held out of training (`model.temperature.val_recordings`)."""
    sampler: dict[str, Any] | None = None
    """The sampler block recorded after training (`model.temperature.sampler_block`)."""


def start_training(cfg: M3GDConfig, req: TrainRequest, device: torch.device,
                   dist: DistInfo | None = None) -> TrainSetup:
    """A new or resumed trainer on `device` (rank `dist`) by the rules in the module doc."""
    mode = req.mode or "full"
    if req.out is None and is_url(cfg.output_dir):
        raise DataError(f"{parse_url(cfg.output_dir)}: checkpoints are not written to object "
                        "storage yet; pass --out DIR")
    out = req.out or cfg.layout.train_of(mode)
    restart = req.resume and unfinished_run(out)
    if req.resume and not restart:
        checkpoint_meta(out)  # no checkpoint: its one line before anything is written
        notes = _prepare_out(out, dist)
        setup = _resumed(cfg, req, device, dist)
        setup.notes = notes
        return setup
    notes = _prepare_out(out, dist)
    if restart:
        notes.insert(0, f"{out} holds no checkpoint (its run stopped before the first save): "
                        "starting over from step 0")
    if has_checkpoint(out) and not req.force:
        raise DataError(f"{out} already holds a checkpoint; --resume to continue it or --force "
                        "to start over")
    req.regime.check()
    stream = open_stream(cfg, "train", mode, cfg.train.seed)
    val = _hold_out_val(stream, req.val_recordings)
    if dist is None or dist.is_main:
        write_run(out, val)  # what `--resume` reads back (`_resumed_val`)
    t = cfg.train
    try:
        net_cfg = replace(net_config_from_cache(stream, mode, req.preset),
                          prediction=req.prediction, anchor=req.anchor, patch=t.patch)
        # the science bench's schedule: warm-up, then cosine decay to lr_min at train.steps
        train_cfg = TrainConfig(lr=t.lr, precision=_precision(cfg), seed=t.seed,
                                grad_accum=t.grad_accum, warmup_steps=t.warmup_steps,
                                decay_steps=max(0, t.steps - t.warmup_steps), lr_min=t.lr_min,
                                ema_decay=t.ema_decay, **req.regime.train_fields())
        trainer = Trainer(net_cfg, train_cfg, device, req.compile, dist)
    except ValueError as err:
        raise DataError(str(err)) from err
    if req.regime.init_from is not None:  # freeze / finetune: the no_lidar weights
        start_from(trainer.net, trainer.ema, req.regime.init_from, net_cfg.c, net_cfg.to_json())
    return TrainSetup(trainer, stream, out, False, notes, val)


def _hold_out_val(stream: ClipStream, n: int) -> list[str]:
    """Remove `n` validation recordings (`model.temperature.val_recordings`) from a training
    stream in place; return their names ([] for n = 0)."""
    if n == 0:
        return []
    held = val_recordings([c["recording"] for c in stream.clips], n)
    hold_out(stream, held, keep=False)
    return held


def _resumed_val(stream: ClipStream, n: int, recorded: list[str] | None, out: Path
                 ) -> list[str]:
    """The validation recordings held out of a resumed run's `stream`: those it recorded
    (`read_run`; else `n` drawn anew); a DataError when `n` (0: not given) asks another count."""
    if recorded is None:
        return _hold_out_val(stream, n)
    if n and n != len(recorded):
        raise DataError(f"{out} was trained holding out {len(recorded)} validation "
                        f"recording(s), not --val-recordings {n}; resume without the option")
    if recorded:
        hold_out(stream, recorded, keep=False)
    return recorded


def unfinished_run(out: Path) -> bool:
    """Whether `out` is the folder of a run stopped before its first checkpoint: no
    checkpoint, but what only m3gd writes there (a save's temporary, the metrics log)."""
    return (out.is_dir() and not has_checkpoint(out)
            and bool(temporaries(out) or (out / FILENAME).is_file()))


def _prepare_out(out: Path, dist: DistInfo | None) -> list[str]:
    """Check that checkpoints can be written into `out` (a one-line DataError naming it:
    read-only, no permission, not a folder) and remove the temporaries of killed saves
    (main rank); return what was done, for the user."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as err:
        raise DataError(f"{out}: checkpoints cannot be written there ({err.strerror or err}); "
                        "choose another --out") from err
    if dist is not None and not dist.is_main:
        return []
    stale = len(temporaries(out))
    freed = remove_temporaries(out)
    return [f"removed {stale} temporary file(s) of killed checkpoint saves from {out} "
            f"({freed / 2**20:.1f} MiB)"] if stale else []


def _precision(cfg: M3GDConfig) -> str:
    """train.precision, or bf16 when the older train.bf16 flag is set."""
    return "bf16" if cfg.train.bf16 and cfg.train.precision == "fp32" else cfg.train.precision


def _resumed(cfg: M3GDConfig, req: TrainRequest, device: torch.device,
             dist: DistInfo | None) -> TrainSetup:
    """The checkpoint in --out (default <output_dir>/train/<mode>), continued."""
    out = req.out or cfg.layout.train_of(req.mode or "full")
    meta = checkpoint_meta(out)
    saved = str(meta["net"]["mode"])
    if req.mode is not None and req.mode != saved:
        raise DataError(f"{out} was trained with --mode {saved}, not {req.mode}")
    stream = open_stream(cfg, "train", saved, int(meta["train"]["seed"]))
    val = _resumed_val(stream, req.val_recordings, read_run(out), out)
    trainer = Trainer.load(out, device, req.compile, dist)
    return TrainSetup(trainer, stream, out, True, val=val)


@dataclass(frozen=True)
class LoopSettings:
    """How long and how: updates, per-rank batch, checkpoint cadence, loader workers, the
    metrics log's cadence and the held-out scoring (every N updates, 0: at the end)."""

    steps: int
    batch_size: int
    every: int = 0
    workers: int = 0
    log_every: int = 10
    eval_every: int = 0
    eval_clips: int = 8
    sample_steps: int = 10
    guidance: float = 1.5


def run_training(cfg: M3GDConfig, setup: TrainSetup, s: LoopSettings,
                 progress: Callable[[int, float, float], None] | None = None,
                 on_score: Callable[[int, dict[str, Any] | None], None] | None = None
                 ) -> list[float]:
    """Train `setup` to s.steps with checkpoints, metrics.jsonl and held-out scores (rank 0
    writes them); progress(step, loss, steps_per_s) after every update; on_score(step, None)
    before a held-out scoring and on_score(step, scores) after it."""
    tr = setup.trainer
    opts = LoopOptions(tr.dist, tr.cfg.grad_accum, s.workers, s.every)
    main = tr.dist.is_main
    log = TrainLog(setup.out / FILENAME if main else None, s.log_every,
                   s.batch_size * tr.dist.world_size * tr.cfg.grad_accum, tr.step_count)
    held_out = _held_out(cfg, setup, s) if main else None

    def on_step(step: int, loss: float) -> None:
        log.on_step(step, loss, tr.opt.param_groups[0]["lr"], tr.last_grad_norm,
                    last=step == s.steps)
        if held_out is not None and (step == s.steps or (s.eval_every
                                                         and step % s.eval_every == 0)):
            t0 = time.perf_counter()
            if on_score is not None:
                on_score(step, None)
            scores = held_out(tr.net)
            log.write({"kind": "eval", "step": step, **scores})
            log.exclude(time.perf_counter() - t0)
            if on_score is not None:
                on_score(step, scores)
        if progress is not None:
            progress(step, loss, log.steps_per_s(step))

    losses = train_loop(tr, setup.stream, s.steps, s.batch_size, setup.out, on_step=on_step,
                        opts=opts)
    if main and setup.val:
        setup.sampler = _choose_sampler(cfg, setup, s)
    return losses


def _choose_sampler(cfg: M3GDConfig, setup: TrainSetup, s: LoopSettings
                    ) -> dict[str, Any] | None:
    """Score K-step samples (s.sample_steps, s.guidance) of the first s.eval_clips clips of
    the validation recordings at every temperature of the grid with the trained (raw)
    weights, record the pick in the checkpoint (`model.temperature`) and return the block;
    None, with a note, where the cache's image encoder has no decoder (nothing to score)."""
    tr = setup.trainer
    seed = tr.cfg.seed
    stream = hold_out(open_stream(cfg, "train", setup.stream.mode, seed, shuffle=False,
                                  with_images=True), setup.val, keep=True)
    try:
        decoder = image_decoder(stream, cfg.encoders.seed)
    except ValueError as err:
        setup.notes.append(f"no sampler temperature chosen: the cache's images cannot be "
                           f"decoded to score samples ({err})")
        return None
    net = tr.net
    was_training = net.training
    net.eval()
    choice = Choice(s.sample_steps, s.guidance, s.eval_clips, s.batch_size, seed)

    def score(t: float) -> tuple[float, int]:
        res = score_clips(net, stream, decoder, choice.clips, choice.batch_size, choice.steps,
                          choice.guidance, None, seed, keep_images=False,
                          image_baselines=False, temperature=t)
        return sum(r.psnr for r in res) / len(res), len({r.clip_id for r in res})

    try:
        block = choose_temperature(score, choice, setup.val)
    finally:
        net.train(was_training)
    record_sampler(setup.out, block)
    return block


def _held_out(cfg: M3GDConfig, setup: TrainSetup, s: LoopSettings
              ) -> Callable[[torch.nn.Module], dict[str, Any]] | None:
    """The held-out scoring of a run's log: on the first eval clips of the cache (None
    without an eval split); PSNR only where the cache's image encoder has a decoder."""
    mode, seed = setup.stream.mode, setup.trainer.cfg.seed
    try:
        stream = open_stream(cfg, "eval", mode, seed, shuffle=False, with_images=True)
    except DataError:
        return None
    try:
        decoder: ImageDecoder | None = image_decoder(stream, cfg.encoders.seed)
    except ValueError:
        decoder = None

    def score(net: torch.nn.Module) -> dict[str, Any]:
        assert isinstance(net, M3GDNet)
        return held_out_scores(net, stream, decoder, s.eval_clips, s.batch_size,
                               s.sample_steps, s.guidance, seed)

    return score


@dataclass(frozen=True)
class ScoreRequest:
    """What `m3gd sample` / `m3gd eval` ask for (None: from the configuration)."""

    clips: int | None
    steps: int | None = None
    guidance: float | None = None
    tol: float | None = None
    ema: bool = False
    batch_size: int | None = None
    keep_images: bool = True
    temperature: float | None = None


def score_checkpoint(cfg: M3GDConfig, checkpoint: Path, req: ScoreRequest,
                     device: torch.device, on_batch: Callable[[int], None] | None = None
                     ) -> tuple[list[TargetResult], ClipStream, dict[str, Any]]:
    """Sample and score eval clips with a checkpoint on `device`: (results, the eval stream,
    the settings used)."""
    meta = checkpoint_meta(checkpoint)
    mode = str(meta["net"]["mode"])
    stream = open_stream(cfg, "eval", mode, cfg.train.seed, shuffle=False, with_images=True)
    try:
        decoder = image_decoder(stream, cfg.encoders.seed)
    except ValueError as err:
        raise DataError(str(err)) from err
    configured = (cfg.sample.temperature if "temperature" in cfg.sample.model_fields_set
                  else None)
    temp, temp_from, note = resolve_temperature(req.temperature, configured, meta)
    check_temperature(temp)  # before the network is loaded and any clip scored
    net, meta = load_net(checkpoint, req.ema, device)
    k = req.steps or cfg.sample.steps
    s = cfg.sample.guidance if req.guidance is None else req.guidance
    tol = cfg.sample.adaptive_tol if req.tol is None else req.tol
    results = score_clips(net, stream, decoder, req.clips, req.batch_size or cfg.train.batch_size,
                          k, s, tol, cfg.train.seed, on_batch, req.keep_images,
                          temperature=temp)
    settings = {"checkpoint": str(checkpoint), "mode": mode, "train_step": int(meta["step"]),
                "weights": "ema" if req.ema else "raw", "steps": k, "guidance": s,
                "adaptive_tol": tol, "temperature": temp, "temperature_from": temp_from}
    if note is not None:
        settings["temperature_note"] = note
    return results, stream, settings
