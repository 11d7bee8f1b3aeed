"""Training loop over a `ClipStream`: updates, periodic checkpoints, exact mid-epoch resume.

The position (epoch, next update of the epoch, global batch) travels in the checkpoint
(`extra["stream"]`), so a resumed run continues with the next unseen global batch of the
same epoch and the same randomness, on any number of ranks with the same global batch.
With several processes (torchrun) every rank runs this loop on its share of each update
(`model.batching`); only rank 0 writes checkpoints.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from model.batching import BatchPlan, TrainBatches, make_train_loader
from model.checkpoint import has_checkpoint, read_meta
from model.dataset import ClipStream
from model.device import pin_memory
from model.distributed import DistInfo
from model.train_step import DivergedError, Trainer
from schemas.errors import DataError, M3GDError

log = logging.getLogger(__name__)

MODEL_KEYS = ("latents", "g", "h", "K", "T_world_cam", "is_target")
"""Batch entries the network reads."""


def model_batch(batch: dict[str, Tensor]) -> dict[str, Tensor]:
    """The entries of a loader batch the network reads (drops bookkeeping like _seq, images)."""
    return {k: batch[k] for k in MODEL_KEYS if k in batch}


def train_batch(batch: dict[str, Tensor]) -> dict[str, Tensor]:
    """What `Trainer.step` reads: the network's entries and the plan's _pos, _weight,
    _n_targets."""
    extra: dict[str, Tensor] = {k: batch[k] for k in ("_pos", "_weight", "_n_targets",
                                                      "_n_views") if k in batch}
    return {**model_batch(batch), **extra}


class TrainingDiverged(M3GDError, FloatingPointError):
    """Training stopped on a non-finite loss or gradient; nothing saved was overwritten.

    step: the update that diverged; last_loss: the last finite loss (None if none);
    checkpoint: the directory to resume from (None if no checkpoint exists).
    """

    def __init__(self, err: DivergedError, last_loss: float | None,
                 checkpoint: Path | None) -> None:
        where = (f"resume from {checkpoint} (step {read_meta(checkpoint)['step']})"
                 if checkpoint is not None else "no checkpoint to resume from")
        last = "none" if last_loss is None else f"{last_loss:.6g}"
        super().__init__(f"{err}; last finite loss {last}; {where}; lower the learning rate "
                         "or raise the warm-up")
        self.step, self.last_loss, self.checkpoint = err.step, last_loss, checkpoint

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled as its message and fields (the constructor reads the checkpoint)."""
        return (_restore, (type(self), self.args, dict(self.__dict__)))


def _restore(cls: type[TrainingDiverged], args: tuple[Any, ...],
             state: dict[str, Any]) -> TrainingDiverged:
    """A TrainingDiverged rebuilt from its message and fields, without reading files."""
    err = cls.__new__(cls)
    Exception.__init__(err, *args)
    err.__dict__.update(state)
    return err


class NonFiniteInput(DataError):
    """A batch whose inputs (latents, packets, cameras) hold NaN or Inf: training stopped
    before any update; the message names the batch entry and the clips (recording, camera,
    views) it came from."""


INPUT_ARRAYS = {"latents": "latents_l0", "h": "h_cells"}
"""The cache array a batch entry was read from, where the names differ."""


def nonfinite_inputs(micro: list[dict[str, Tensor]], stream: ClipStream) -> str:
    """Where the float entries of a batch's micro-batches hold NaN or Inf: '<entry> (cache
    array <name>) of <recording>/<camera> views [...]', '; '-joined ('' if all finite).
    Checked only after a divergence (no cost on the normal path)."""
    clips = {int(c["clip_id"]): c for c in stream.clips}
    found: list[str] = []
    for mb in micro:
        ids = [int(i) for i in mb["clip_id"].reshape(-1).tolist()] if "clip_id" in mb else []
        for key, value in mb.items():
            if not value.is_floating_point() or bool(torch.isfinite(value).all()):
                continue
            array = INPUT_ARRAYS.get(key, key)
            if value.dim() >= 2 and value.shape[0] == len(ids) and key != "h":
                bad = (~torch.isfinite(value)).reshape(len(ids), -1).any(1).tolist()
                where = [clips.get(i) for i, b in zip(ids, bad, strict=True) if b]
            else:  # packed rows of several clips: every clip of the micro-batch
                where = [clips.get(i) for i in ids]
            places = sorted({f"{c['recording']}/{c['camera']} views "
                             f"{sorted(int(f) for f in c['frames'])}" for c in where if c})
            found.append(f"{key} (cache array {array}) of {', '.join(places) or 'the batch'}")
    return "; ".join(dict.fromkeys(found))


@dataclass
class Position:
    """Where an epoch stands: the epoch and its next update; with the global batch it holds."""

    epoch: int = 0
    step: int = 0
    global_batch: int = 0

    def to_json(self) -> dict[str, int]:
        """The checkpoint's extra["stream"]."""
        return {"epoch": self.epoch, "step": self.step, "global_batch": self.global_batch}

    @classmethod
    def of(cls, trainer: Trainer) -> Position:
        """The position saved with a trainer's checkpoint (the start for a new trainer)."""
        saved: dict[str, Any] = trainer.extra.get("stream", {})
        if "consumed" in saved:  # format 1: per-worker sample counts of another order
            log.warning("checkpoint from an older m3gd: epoch %s restarts from its beginning",
                        saved.get("epoch", 0))
            return cls(int(saved.get("epoch", 0)))
        return cls(int(saved.get("epoch", 0)), int(saved.get("step", 0)),
                   int(saved.get("global_batch", 0)))


@dataclass(frozen=True)
class LoopOptions:
    """Ranks, gradient accumulation, loader workers, checkpoint cadence of a training run."""

    dist: DistInfo = field(default_factory=DistInfo)
    accum: int = 1
    num_workers: int = 0
    every: int = 0


def train_loop(trainer: Trainer, stream: ClipStream, steps: int, batch_size: int,
               ckpt_dir: Path | None = None, every: int = 0, num_workers: int = 0,
               on_step: Callable[[int, float], None] | None = None,
               opts: LoopOptions | None = None) -> list[float]:
    """Train until `trainer.step_count == steps`; returns the losses of the updates run here.

    batch_size is per rank and micro-batch (`opts`: ranks, accumulation). Checkpoints to
    `ckpt_dir` every `every` updates and at the end (rank 0 only). A non-finite loss or
    gradient raises `TrainingDiverged` without saving anything.
    """
    opts = opts or LoopOptions(num_workers=num_workers, every=every)
    plan = BatchPlan(len(stream.clips), batch_size, trainer.dist.world_size, opts.accum)
    pos = Position.of(trainer)
    if pos.global_batch and pos.global_batch != plan.global_batch and pos.step:
        raise DataError(f"{ckpt_dir}: saved mid-epoch with a global batch of "
                        f"{pos.global_batch} clips, resumed with {plan.global_batch} "
                        "(batch x ranks x accumulation); use the same or start over")
    pos.global_batch = plan.global_batch
    losses: list[float] = []
    try:
        _run(trainer, stream, plan, steps, pos, ckpt_dir, opts, on_step, losses)
    except DivergedError as err:
        saved = ckpt_dir if ckpt_dir is not None and has_checkpoint(ckpt_dir) else None
        raise TrainingDiverged(err, losses[-1] if losses else None, saved) from err
    _save(trainer, ckpt_dir, pos)
    return losses


def _save(trainer: Trainer, ckpt_dir: Path | None, pos: Position) -> None:
    """Checkpoint on rank 0 (the others hold the same weights)."""
    if ckpt_dir is not None and trainer.dist.is_main:
        trainer.save(ckpt_dir, extra={"stream": pos.to_json()})


def _run(trainer: Trainer, stream: ClipStream, plan: BatchPlan, steps: int, pos: Position,
         ckpt_dir: Path | None, opts: LoopOptions,
         on_step: Callable[[int, float], None] | None, losses: list[float]) -> None:
    """The updates of `train_loop`, appending to `losses` and moving `pos`."""
    if plan.n_clips == 0:
        raise DataError(f"clip stream over {stream.cache} holds no clip")
    while trainer.step_count < steps:
        batches = TrainBatches(stream, plan, trainer.dist.rank, pos.epoch, pos.step)
        loader = make_train_loader(batches, opts.num_workers, pin_memory(trainer.device))
        for item in loader:
            try:
                losses.append(trainer.step([train_batch(b) for b in item["micro"]]))
            except DivergedError as err:
                bad = nonfinite_inputs(item["micro"], stream)
                if bad:  # the data, not the optimizer: name it, no advice on the lr
                    raise NonFiniteInput(f"training stopped at step {err.step}: the input "
                                         f"holds non-finite values ({bad}); the cache arrays "
                                         "there are damaged or were written so: rebuild "
                                         "them (`m3gd run --force encode`) or leave that "
                                         "recording out") from err
                raise
            pos.step = int(item["step"]) + 1
            if on_step is not None:
                on_step(trainer.step_count, losses[-1])
            if opts.every and trainer.step_count % opts.every == 0:
                _save(trainer, ckpt_dir, pos)
            if trainer.step_count >= steps:
                return
        pos.epoch, pos.step = pos.epoch + 1, 0


def resume(ckpt_dir: Path, **trainer_kw: Any) -> Trainer:
    """Trainer from a checkpoint (`trainer_kw`: device, compile, dist of `Trainer.load`);
    `train_loop` continues from the position saved in it."""
    return Trainer.load(ckpt_dir, **trainer_kw)
