"""Device strings and precision: what this CPU-only machine can check of the CUDA path."""

from __future__ import annotations

import pytest
import torch

from model.device import autocast, grad_scaler, pin_memory, resolve_device, to_device
from model.distributed import DistInfo, device_of
from schemas.errors import DataError


def test_auto_is_cuda_only_when_available() -> None:
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert resolve_device("auto").type == expected
    assert resolve_device("cpu") == torch.device("cpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_cuda_without_a_gpu_is_refused_in_one_line() -> None:
    with pytest.raises(DataError, match="sees no CUDA GPU") as info:
        resolve_device("cuda:0")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("bad", ["gpu", "cuda:", "cuda:a", "CPU", ""])
def test_unknown_device_strings(bad: str) -> None:
    with pytest.raises(DataError, match="unknown"):
        resolve_device(bad)


def test_cuda_only_switches_are_off_on_the_cpu() -> None:
    cpu = torch.device("cpu")
    assert not pin_memory(cpu) and pin_memory(torch.device("cuda", 0))
    assert not grad_scaler(cpu, "bf16").is_enabled() and grad_scaler(cpu, "fp16").is_enabled()
    batch = {"x": torch.ones(2)}
    assert to_device(batch, cpu)["x"] is batch["x"]


@pytest.mark.parametrize(("precision", "dtype"), [("fp32", torch.float32),
                                                  ("bf16", torch.bfloat16),
                                                  ("fp16", torch.float16)])
def test_autocast_runs_matmuls_in_the_precision(precision: str, dtype: torch.dtype) -> None:
    lin = torch.nn.Linear(4, 4)
    with autocast(torch.device("cpu"), precision):
        assert lin(torch.ones(2, 4)).dtype == dtype


def test_a_cpu_device_stays_the_cpu_on_every_rank() -> None:
    """(The cuda -> cuda:LOCAL_RANK branch needs a GPU: not run here.)"""
    assert device_of("cpu", DistInfo(3, 4, 1)) == torch.device("cpu")
