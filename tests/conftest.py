"""Suite-wide settings: one torch thread (2-core machines stall otherwise), Agg plots, the same
torch seed before every test, the random order's seed printed."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

import torch

torch.set_num_threads(1)

pytest_plugins = ["tests.s3_fixture"]  # s3 / s3_env: a moto S3 server on 127.0.0.1


@pytest.fixture(autouse=True)
def _torch_seed() -> None:
    """Every test starts from the same global torch generator state, whatever ran before it
    (pytest-randomly reseeds `random` and numpy's global generator, not torch's)."""
    torch.manual_seed(0)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter,
                            config: pytest.Config) -> None:
    """Print the random test order's seed (pytest-randomly) even under -q; a failure that
    depends on the order is repeated with `pytest --randomly-seed=N`."""
    seed = getattr(config.option, "randomly_seed", None)
    if config.pluginmanager.has_plugin("randomly") and seed is not None:
        terminalreporter.write_line(f"test order: --randomly-seed={seed}")
