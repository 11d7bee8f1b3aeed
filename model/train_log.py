"""Scalars of a training run as JSON lines: `<checkpoint dir>/metrics.jsonl`.

Two kinds of line, each one JSON object:
  {"kind": "train", "step", "loss" (mean over the lines' window), "lr", "grad_norm",
   "steps_per_s", "clips_per_s", "seconds" (since the log was opened)}
  {"kind": "eval", "step", "val_loss_t": [per t of model.validation.T_GRID],
   "val_loss_mean", "psnr_model", "psnr_copy_source", "psnr_mean_latent", "eval_clips"}
A resumed run first drops the lines past its checkpoint's step (a killed run logged steps it
then lost), so the log reads as one run. `m3gd plot` draws it (pipeline.analysis.plots).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from schemas.atomic_io import write_text_atomic

FILENAME = "metrics.jsonl"


def read_log(path: Path) -> list[dict[str, Any]]:
    """Every record of a metrics log (skips a last line cut by a kill)."""
    records = []
    for line in path.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


class TrainLog:
    """Appends train lines every `every` updates and eval lines when given; rank 0 only."""

    def __init__(self, path: Path | None, every: int, clips_per_update: int,
                 start_step: int) -> None:
        self.path, self.every, self.clips_per_update = path, every, clips_per_update
        self.t0 = self.t_last = time.perf_counter()
        self.step_last = self.start_step = start_step
        self.excluded = 0.0  # seconds spent outside updates (held-out scoring)
        self.losses: list[float] = []
        if path is not None and path.exists():
            kept = [r for r in read_log(path) if int(r.get("step", 0)) <= start_step]
            write_text_atomic(path, "".join(json.dumps(r) + "\n" for r in kept))

    def rate(self, step: int) -> float:
        """Updates per second since the last train line."""
        dt = time.perf_counter() - self.t_last
        return (step - self.step_last) / dt if dt > 0 else 0.0

    def on_step(self, step: int, loss: float, lr: float, grad_norm: float,
                last: bool = False) -> dict[str, Any] | None:
        """Record one update; every `every` updates (and at the `last`) write and return a
        train line."""
        self.losses.append(loss)
        if step % self.every and not last:
            return None
        rate = self.rate(step)
        rec = {"kind": "train", "step": step, "loss": sum(self.losses) / len(self.losses),
               "lr": lr, "grad_norm": grad_norm, "steps_per_s": rate,
               "clips_per_s": rate * self.clips_per_update,
               "seconds": time.perf_counter() - self.t0}
        self.losses.clear()
        self.t_last, self.step_last = time.perf_counter(), step
        self.write(rec)
        return rec

    def steps_per_s(self, step: int) -> float:
        """Updates per second since the log was opened, time outside updates excluded."""
        dt = time.perf_counter() - self.t0 - self.excluded
        return (step - self.start_step) / dt if dt > 0 else 0.0

    def exclude(self, seconds: float) -> None:
        """Leave `seconds` spent outside updates (held-out scoring) out of the rates."""
        self.excluded += seconds
        self.t_last += seconds

    def write(self, record: dict[str, Any]) -> None:
        """Append one record (a line) to the log."""
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("a") as f:
            f.write(json.dumps(record) + "\n")
