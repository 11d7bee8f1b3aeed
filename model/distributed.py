"""Several processes, one model: torch.distributed as torchrun sets it up.

`torchrun --nproc-per-node N -m cli train ...` starts N processes and gives each RANK,
WORLD_SIZE, LOCAL_RANK, MASTER_ADDR and MASTER_PORT in its environment (several machines:
the same command on each with --nnodes and --rdzv-endpoint). `from_env()` reads them; a
plain `m3gd train` is rank 0 of 1 and never touches torch.distributed. The backend is NCCL
on CUDA devices and gloo otherwise (the tests run gloo on the CPU).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist

from model.device import resolve_device


@dataclass(frozen=True)
class DistInfo:
    """This process's place: global rank, number of processes, rank on its machine."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        """Rank 0: the one that writes checkpoints, logs and prints."""
        return self.rank == 0

    @property
    def active(self) -> bool:
        """More than one process: gradients and scalars are reduced across them."""
        return self.world_size > 1


def from_env() -> DistInfo:
    """Rank, world size and local rank from torchrun's environment (0, 1, 0 without it)."""
    return DistInfo(int(os.environ.get("RANK", "0")), int(os.environ.get("WORLD_SIZE", "1")),
                    int(os.environ.get("LOCAL_RANK", "0")))


def device_of(spec: str, info: DistInfo) -> torch.device:
    """The device of this rank: `spec` resolved; a bare "cuda" (or "auto" on a CUDA machine)
    becomes cuda:LOCAL_RANK so every process of a machine drives its own GPU."""
    dev = resolve_device(spec)
    if dev.type == "cuda" and dev.index is None and info.active:
        return torch.device("cuda", info.local_rank)
    return dev


def init(info: DistInfo, device: torch.device, timeout_s: float = 600.0) -> None:
    """Join the process group of a multi-process run (no-op for one process)."""
    if not info.active or dist.is_initialized():
        return
    if device.type == "cuda":
        torch.cuda.set_device(device)
    backend = "nccl" if device.type == "cuda" else "gloo"
    dist.init_process_group(backend, rank=info.rank, world_size=info.world_size,
                            timeout=timedelta(seconds=timeout_s))


def shutdown() -> None:
    """Leave the process group, if one was joined."""
    if dist.is_initialized():
        dist.destroy_process_group()


def all_sum(x: torch.Tensor) -> torch.Tensor:
    """Sum of `x` over all ranks (x itself with one process)."""
    if not dist.is_initialized():
        return x
    y = x.clone()
    dist.all_reduce(y)
    return y


def barrier() -> None:
    """Wait for every rank (no-op with one process)."""
    if dist.is_initialized():
        dist.barrier()
