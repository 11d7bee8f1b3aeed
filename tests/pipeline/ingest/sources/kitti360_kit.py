"""The KITTI-360 copy of a small synthetic recording, made once per test session."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from pipeline.synth.kitti360_write import bags_to_kitti360
from schemas.config import IngestConfig, TopicsConfig
from tests.pipeline.ingest.sources.hf.kit import mission

SEQ = "2013_05_28_drive_0000_sync"
CAMERAS = ["front", "left"]
"""The bag cameras written as image_00, image_01."""
INGEST = IngestConfig(out_height=112, out_width=168, cameras=CAMERAS)


def kitti_root(factory: pytest.TempPathFactory, name: str = "clean") -> Path:
    """The KITTI-360 root of synthkit recording `name` (its bags: `bags_of`)."""
    root = factory.getbasetemp() / "kitti360_kit" / name
    if not (root / "calibration" / "calib_cam_to_velo.txt").exists():
        shutil.rmtree(root, ignore_errors=True)
        bags = sorted(bags_of(factory, name).glob("*.bag"))
        bags_to_kitti360(bags, root, TopicsConfig(), CAMERAS, SEQ)
    return root


def bags_of(factory: pytest.TempPathFactory, name: str = "clean") -> Path:
    """The bag mission folder of synthkit recording `name`."""
    return mission(factory, name, "rosbag")


def copy_of(factory: pytest.TempPathFactory, tmp: Path, name: str = "clean") -> Path:
    """A private copy of the KITTI-360 root that a test may damage."""
    dst = tmp / f"k360_{name}"
    shutil.copytree(kitti_root(factory, name), dst)
    return dst
