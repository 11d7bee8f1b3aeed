"""Tiny synthetic missions shared by the synth tests (generated once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.synth.api import SynthResult, synthesize
from schemas.config import SynthConfig

TINY = {"seconds": 1.5, "image_width": 128, "image_height": 96, "points_per_sweep": 2048}
ALL_FAULTS = [
    "truncated_bag", "corrupt_jpeg", "nan_points", "empty_sweep", "missing_camera_info",
    "missing_tf_edge", "duplicate_stamps", "out_of_order_stamps", "camera_gap", "lidar_gap",
]  # fmt: skip


@pytest.fixture(scope="session")
def clean(tmp_path_factory: pytest.TempPathFactory) -> SynthResult:
    """A fault-free corridor mission (1.5 s, 3 cameras)."""
    return synthesize(tmp_path_factory.mktemp("clean"), SynthConfig(**TINY), "corridor")


@pytest.fixture(scope="session")
def faulty(tmp_path_factory: pytest.TempPathFactory) -> SynthResult:
    """A warehouse mission (3 s) with every fault kind injected."""
    cfg = SynthConfig(**{**TINY, "seconds": 3.0, "faults": ALL_FAULTS})
    return synthesize(tmp_path_factory.mktemp("faulty"), cfg, "warehouse")


def tiny_dir(result: SynthResult) -> Path:
    """The mission folder of a result."""
    return result.mission_dir
