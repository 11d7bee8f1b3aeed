"""Training batches of one epoch, dealt over ranks, loader workers and micro-batches.

An epoch is one seeded order of every training clip (`ClipStream.epoch_order`: shard units
shuffled, clips shuffled inside a unit, so a batch reads few shards). Update k takes the
global batch order[k G : (k + 1) G], G = batch x ranks x accumulation steps; its slot
s = micro x ranks + rank is the micro-batch `micro` of rank `rank`:
order[k G + s b : k G + (s + 1) b]. So every clip is read once per epoch by exactly one
rank and one loader worker (worker w of a rank reads the updates k = start + w (mod W)), the
last global batch is used however short, and the clips of an update do not depend on how
it is split. A slot past the end of a short last batch gets a padding clip of weight 0
(its gradient is zero; ranks only stay in step). Resuming needs (epoch, next update) only.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import torch
from torch.utils.data import IterableDataset, get_worker_info

from model.dataset import ClipStream, collate_clips


@dataclass(frozen=True)
class BatchPlan:
    """Sizes of the deal: clips in the epoch, per-rank micro-batch b, ranks R, accumulation A."""

    n_clips: int
    batch_size: int
    world_size: int = 1
    accum: int = 1

    @property
    def global_batch(self) -> int:
        """G = b x R x A clips per update."""
        return self.batch_size * self.world_size * self.accum

    def updates(self) -> int:
        """Updates in one epoch: ceil(n_clips / G) (the last one may be short)."""
        return math.ceil(self.n_clips / self.global_batch)

    def global_range(self, step: int) -> range:
        """Positions in the epoch order of the clips of update `step`."""
        lo = step * self.global_batch
        return range(lo, min(lo + self.global_batch, self.n_clips))

    def slot(self, step: int, rank: int, micro: int) -> range:
        """Positions of micro-batch `micro` of rank `rank` in update `step` (may be empty)."""
        whole = self.global_range(step)
        lo = whole.start + (micro * self.world_size + rank) * self.batch_size
        return range(min(lo, whole.stop), min(lo + self.batch_size, whole.stop))


class TrainBatches(IterableDataset[dict[str, Any]]):
    """One rank's updates of one epoch from `start`: items {"step": k, "micro": [A batches]}.

    Every micro-batch carries _pos (positions in the global batch), _weight (0 for padding)
    and _n_targets (target views of the whole global batch; _n_views: all its views) for
    `model.train_step`.
    """

    def __init__(self, stream: ClipStream, plan: BatchPlan, rank: int, epoch: int,
                 start: int = 0) -> None:
        self.stream, self.plan, self.rank, self.epoch, self.start = (stream, plan, rank, epoch,
                                                                     start)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        info = get_worker_info()
        n_workers, wid = (info.num_workers, info.id) if info is not None else (1, 0)
        if info is not None:
            torch.set_num_threads(1)
        order = self.stream.epoch_order(self.epoch)
        for k in range(self.start + wid, self.plan.updates(), n_workers):
            yield {"step": k, "micro": [self.micro_batch(order, k, m)
                                        for m in range(self.plan.accum)]}

    def micro_batch(self, order: list[int], step: int, micro: int) -> dict[str, torch.Tensor]:
        """Micro-batch `micro` of this rank in update `step` (a weight-0 pad when empty)."""
        whole = self.plan.global_range(step)
        slot = self.plan.slot(step, self.rank, micro)
        positions, weight = (list(slot), 1.0) if len(slot) else ([whole.start], 0.0)
        clips = [self.stream.clips[order[p]] for p in positions]
        batch = collate_clips([self.stream.read_clip(c) for c in clips])
        n_targets = sum(sum(self.stream.clips[order[p]]["is_target"]) for p in whole)
        batch["_pos"] = torch.tensor([p - whole.start for p in positions])
        batch["_weight"] = torch.full((len(positions),), weight)
        batch["_n_targets"] = torch.tensor(n_targets)
        batch["_n_views"] = torch.tensor(sum(len(self.stream.clips[order[p]]["is_target"])
                                             for p in whole))  # the all-views loss's count
        return batch


def make_train_loader(batches: TrainBatches, num_workers: int = 0, pin: bool = False) -> Any:
    """DataLoader over one rank's updates, in update order; spawned workers (tensorstore
    forbids fork), host memory pinned when `pin` (a CUDA device)."""
    from torch.utils.data import DataLoader

    ctx = "spawn" if num_workers > 0 else None
    return DataLoader(batches, batch_size=None, num_workers=num_workers,
                      multiprocessing_context=ctx, persistent_workers=False, pin_memory=pin)
