"""Recordings for the proof on every source: the proof tests' dense corridor (`provekit`)
converted to the Hugging Face layout and to the KITTI-360 layout, and written with another
point-time convention or speed; each written once per session."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from pipeline.synth.api import synthesize
from pipeline.synth.hf_convert import bags_to_hf
from pipeline.synth.kitti360_write import bags_to_kitti360
from schemas.config import SynthConfig, TopicsConfig
from tests.pipeline.inspect.provekit import DENSE, base_mission

SEQ = "2013_05_28_drive_0000_sync"


def hf_mission(factory: pytest.TempPathFactory) -> Path:
    """The dense corridor in the Hugging Face layout (Zarr v2 store, JPEG folders)."""
    base = base_mission(factory)
    dst = base.parent / "hf"
    if not (dst / "data").exists():
        bags_to_hf(sorted(base.glob("*.bag")), dst, TopicsConfig(), ["front"])
    return dst


def kitti_root(factory: pytest.TempPathFactory) -> Path:
    """The dense corridor in the KITTI-360 layout (camera front as image_00)."""
    base = base_mission(factory)
    dst = base.parent / "kitti360"
    if not (dst / "calibration" / "calib_cam_to_velo.txt").exists():
        bags_to_kitti360(sorted(base.glob("*.bag")), dst, TopicsConfig(), ["front"], SEQ)
    return dst


def synth_dense(factory: pytest.TempPathFactory, name: str, **keys: Any) -> Path:
    """The dense corridor written with other synth keys (a sensor `variant`, `speed_mps`)."""
    root = factory.getbasetemp() / "prove_recordings"
    mission = root / name
    if not (mission / "groundtruth" / "faults.json").exists():
        synthesize(root, SynthConfig(seed=2, scenes=["corridor"], **{**DENSE, **keys}),
                   "corridor", name)  # fmt: skip
    return mission
