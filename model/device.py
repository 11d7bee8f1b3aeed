"""Where the model runs: device choice, mixed precision, host-to-device copies.

One code path for every device. The trainer, the sampler and the frozen encoders take a
`torch.device` and never branch on its type except in this module (autocast's device type,
pinned memory, non-blocking copies). The machines this project is tested on have no GPU:
the CUDA path is the same code exercised with `device=cpu` (autocast bf16/fp16 on CPU, the
GradScaler on CPU), and the CUDA-only switches below (pinned memory, non-blocking copies)
are the documented PyTorch ones, not run here.

Device strings: "auto" (CUDA when available, else CPU), "cpu", "cuda", "cuda:N", "mps".
"""

from __future__ import annotations

import contextlib
import re

import torch
from torch import Tensor

from schemas.errors import DataError

DEVICE_PATTERN = r"^(auto|cpu|mps|cuda(:[0-9]+)?)$"
"""Accepted device strings (also checked by schemas.config)."""
PRECISIONS = ("fp32", "bf16", "fp16")
"""Compute precisions of the trainer: float32, or autocast to bfloat16 / float16."""
_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


def resolve_device(spec: str) -> torch.device:
    """The torch device of a device string; refuses one this machine does not have.

    "auto" is "cuda" when `torch.cuda.is_available()`, else "cpu" (MPS only when asked for).
    """
    if not re.match(DEVICE_PATTERN, spec):
        raise DataError(f"device {spec!r} unknown; one of auto, cpu, cuda, cuda:N, mps")
    if spec == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    dev = torch.device(spec)
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise DataError(f"device {spec!r}: this torch ({torch.__version__}) sees no CUDA "
                            "GPU; use --device cpu or install a CUDA build of torch")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise DataError(f"device {spec!r}: only {torch.cuda.device_count()} CUDA "
                            "device(s) visible")
    if dev.type == "mps" and not torch.backends.mps.is_available():
        raise DataError(f"device {spec!r}: MPS is not available on this machine")
    return dev


def check_precision(precision: str) -> str:
    """`precision` if it is one of `PRECISIONS`, else a one-line DataError."""
    if precision not in PRECISIONS:
        raise DataError(f"precision {precision!r} unknown; one of {', '.join(PRECISIONS)}")
    return precision


def autocast(device: torch.device, precision: str) -> contextlib.AbstractContextManager[None]:
    """Autocast to the precision's dtype on `device` (a no-op context for fp32)."""
    check_precision(precision)
    if precision == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device.type, dtype=_DTYPES[precision])


def grad_scaler(device: torch.device, precision: str) -> torch.amp.GradScaler:
    """Loss scaler: active for fp16 only (bf16 has float32's range and needs none)."""
    return torch.amp.GradScaler(device.type, enabled=precision == "fp16")


def pin_memory(device: torch.device) -> bool:
    """Whether the loader should pin host memory: only for a CUDA device."""
    return device.type == "cuda"


def to_device(batch: dict[str, Tensor], device: torch.device) -> dict[str, Tensor]:
    """Every tensor of a batch on `device`; copies from pinned memory do not block on CUDA."""
    non_blocking = device.type == "cuda"
    return {k: v.to(device, non_blocking=non_blocking) for k, v in batch.items()}



def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously; timings need this)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
