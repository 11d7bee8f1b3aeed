"""Synthetic recordings for the ingest/select done-when tests, made once per test session.

Small sizes (240x160 images, 2048 points per sweep, a few seconds) keep the suite fast; the
recordings are cached under the session's base temp folder and shared by every test module.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.synth.api import synthesize
from schemas.config import IngestConfig, SynthConfig

SMALL = {"image_width": 240, "image_height": 160, "points_per_sweep": 2048}
RECORDINGS: dict[str, dict[str, Any]] = {
    "clean": {"seconds": 2.0},
    "faulty": {
        "seconds": 3.0,
        "faults": ["corrupt_jpeg", "duplicate_stamps", "out_of_order_stamps", "nan_points",
                   "empty_sweep", "missing_camera_info", "camera_gap", "lidar_gap"],
    },
    "truncated": {"seconds": 1.5, "cameras": ["front"], "faults": ["truncated_bag"]},
    "no_tf": {"seconds": 0.5, "cameras": ["front", "right"], "faults": ["missing_tf_edge"]},
}
INGEST = IngestConfig(out_height=112, out_width=168)
"""Output 112x168 (3:2, multiples of 14): below the raw 160x240, as 224x336 is below 1280x1920."""


def recording(factory: pytest.TempPathFactory, name: str) -> Path:
    """Mission folder of recording `name`, synthesized on first use in this session."""
    root = factory.getbasetemp() / "synth_recordings"
    mission = root / name
    if not (mission / "groundtruth" / "faults.json").exists():
        cfg = SynthConfig(seed=3, scenes=["corridor"], **{**SMALL, **RECORDINGS[name]})
        synthesize(root, cfg, "corridor", name)
    return mission


def gt_table(mission: Path, name: str) -> list[dict[str, Any]]:
    """Rows of a ground-truth Parquet table (images, sweeps, poses)."""
    path = mission / "groundtruth" / f"{name}.parquet"
    rows: list[dict[str, Any]] = pq.read_table(path).to_pylist()
    return rows


def gt_json(mission: Path, name: str) -> Any:
    """A ground-truth JSON file (calibration, faults, scene, config)."""
    return json.loads((mission / "groundtruth" / f"{name}.json").read_text())


def gt_T_base(mission: Path, sensor: str) -> np.ndarray:
    """(4, 4) ground-truth T_base_sensor ('front', 'left', 'right', 'lidar')."""
    return np.asarray(gt_json(mission, "calibration")["T_base_sensor"][sensor], dtype=np.float64)
