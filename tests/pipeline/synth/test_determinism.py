"""Same config and scene give the same mission byte for byte; another seed does not."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import zarr

from pipeline.synth.api import synthesize
from schemas.config import SynthConfig

CFG = {"seconds": 0.6, "image_width": 96, "image_height": 64, "points_per_sweep": 512,
       "cameras": ["front", "right"], "faults": ["corrupt_jpeg", "nan_points"]}  # fmt: skip


def _digests(d: Path) -> dict[str, str]:
    """sha256 of every bag, Parquet and JSON file under a mission folder, by relative path."""
    files = [p for p in sorted(d.rglob("*")) if p.suffix in {".bag", ".parquet", ".json"}]
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    a = synthesize(tmp_path / "a", SynthConfig(**CFG), "plaza")
    b = synthesize(tmp_path / "b", SynthConfig(**CFG), "plaza")
    da, db = _digests(a.mission_dir), _digests(b.mission_dir)
    assert len(da) == 5 + 3 + 4 + 2 and da == db  # bags, Parquet, JSON, zarr.json
    za = zarr.open_array(str(a.groundtruth_dir / "depth" / "right.zarr"))[:]
    zb = zarr.open_array(str(b.groundtruth_dir / "depth" / "right.zarr"))[:]
    np.testing.assert_array_equal(za, zb)


def test_other_seed_other_recording(tmp_path: Path) -> None:
    a = synthesize(tmp_path / "a", SynthConfig(**CFG), "plaza")
    c = synthesize(tmp_path / "c", SynthConfig(**{**CFG, "seed": 1}), "plaza")
    da, dc = _digests(a.mission_dir), _digests(c.mission_dir)
    bags = [k for k in da if k.endswith(".bag")]
    assert all(da[k] != dc[k.replace("_s0", "_s1")] for k in bags)


def test_rerun_replaces_previous_mission(tmp_path: Path) -> None:
    a = synthesize(tmp_path, SynthConfig(**CFG), "plaza")
    before = _digests(a.mission_dir)
    b = synthesize(tmp_path, SynthConfig(**CFG), "plaza")
    assert _digests(b.mission_dir) == before
