"""Training loop over a `ClipStream`: steps, periodic checkpoints, exact mid-epoch resume.

The stream's state dict travels in the checkpoint JSON (`extra["stream"]`), so a resumed run
continues with the next unseen clip of the same epoch and the same trainer randomness.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from torch import Tensor

from model.dataset import ClipStream, make_loader
from model.train_step import DivergedError, Trainer
from schemas.errors import DataError, M3GDError

MODEL_KEYS = ("latents", "g", "h", "K", "T_world_cam", "is_target")
"""Batch entries the network reads."""


def model_batch(batch: dict[str, Tensor]) -> dict[str, Tensor]:
    """The entries of a loader batch the network reads (drops bookkeeping like _seq, images)."""
    return {k: batch[k] for k in MODEL_KEYS if k in batch}


class TrainingDiverged(M3GDError, FloatingPointError):
    """Training stopped on a non-finite loss or gradient; nothing saved was overwritten.

    step: the update that diverged; last_loss: the last finite loss (None if none);
    checkpoint: the directory to resume from (None if no checkpoint exists).
    """

    def __init__(self, err: DivergedError, last_loss: float | None,
                 checkpoint: Path | None) -> None:
        where = (f"resume from {checkpoint} (step {_saved_step(checkpoint)})"
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


def _saved_step(checkpoint: Path) -> int:
    """Step recorded in a checkpoint directory."""
    import json

    return int(json.loads((checkpoint / "state.json").read_text())["step"])


def train_loop(trainer: Trainer, stream: ClipStream, steps: int, batch_size: int,
               ckpt_dir: Path | None = None, every: int = 0, num_workers: int = 0,
               on_step: Callable[[int, float], None] | None = None) -> list[float]:
    """Train until `trainer.step_count == steps`; returns the losses of the steps run here.

    Checkpoints to `ckpt_dir` every `every` steps (0: only at the end, if ckpt_dir is set).
    Epochs roll over by `stream.set_epoch(epoch + 1)`; the last partial batch is used.
    A non-finite loss or gradient raises `TrainingDiverged` without saving anything.
    """
    losses: list[float] = []
    try:
        _run(trainer, stream, steps, batch_size, ckpt_dir, every, num_workers, on_step, losses)
    except DivergedError as err:
        saved = ckpt_dir if ckpt_dir is not None and (ckpt_dir / "state.json").exists() else None
        raise TrainingDiverged(err, losses[-1] if losses else None, saved) from err
    if ckpt_dir is not None:
        trainer.save(ckpt_dir, extra={"stream": stream.state_dict()})
    return losses


def _run(trainer: Trainer, stream: ClipStream, steps: int, batch_size: int,
         ckpt_dir: Path | None, every: int, num_workers: int,
         on_step: Callable[[int, float], None] | None, losses: list[float]) -> None:
    """The steps of `train_loop`, appending to `losses`."""
    while trainer.step_count < steps:
        n_before = trainer.step_count
        for batch in make_loader(stream, batch_size, num_workers):
            stream.update(batch)
            losses.append(trainer.step(model_batch(batch)))
            if on_step is not None:
                on_step(trainer.step_count, losses[-1])
            if ckpt_dir is not None and every and trainer.step_count % every == 0:
                trainer.save(ckpt_dir, extra={"stream": stream.state_dict()})
            if trainer.step_count >= steps:
                break
        else:
            if trainer.step_count == n_before:
                raise DataError(f"clip stream over {stream.cache} yielded no batch "
                                 f"({len(stream.clips)} clips)")
            stream.set_epoch(stream.state.epoch + 1)


def resume(ckpt_dir: Path, stream: ClipStream) -> Trainer:
    """Trainer from a checkpoint, with `stream` moved to the saved position."""
    trainer = Trainer.load(ckpt_dir)
    if "stream" in trainer.extra:
        stream.load_state_dict(trainer.extra["stream"])
    return trainer
