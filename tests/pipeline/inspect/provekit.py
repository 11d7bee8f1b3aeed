"""Recordings for the proof tests: a synthetic corridor dense enough for the geometry verdict
to fail a wrong geometry (8192 points a sweep: a 1.4 deg azimuth step, the verdict needs 1.5 at
most), written once per session, copied and changed per variant."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

from pipeline.synth.api import synthesize
from pipeline.synth.variants_rig import rewrite_bag, ros1_typestore
from pipeline.synth.variants_tf import apply_tf_variant
from schemas.config import SynthConfig, TopicsConfig

DENSE = {"seconds": 3.0, "image_width": 192, "image_height": 128, "points_per_sweep": 8192,
         "cameras": ["front"], "depth_maps": False}  # fmt: skip
TOPICS = TopicsConfig()
FRONT = TOPICS.image_topic("front")
FRONT_INFO = TOPICS.info_topic("front")


def base_mission(factory: pytest.TempPathFactory) -> Path:
    """The dense corridor mission `dense`, written once per session."""
    root = factory.getbasetemp() / "prove_recordings"
    mission = root / "dense"
    if not (mission / "groundtruth" / "faults.json").exists():
        synthesize(root, SynthConfig(seed=2, scenes=["corridor"], **DENSE), "corridor", "dense")
    return mission


def variant(factory: pytest.TempPathFactory, name: str) -> Path:
    """A copy of the dense mission with TF variant `name` applied
    (`pipeline.synth.variants_tf`)."""
    base = base_mission(factory)
    mission = base.parent / name
    if not mission.exists():
        shutil.copytree(base, mission)
        apply_tf_variant(mission, name, FRONT, (TOPICS.lidar, TOPICS.lidar_frame))
    return mission


def restamped(factory: pytest.TempPathFactory, name: str, frames: dict[str, str]) -> Path:
    """A copy of the dense mission whose messages of each topic of `frames` carry that
    frame_id (a driver configured with another camera's frame)."""
    base = base_mission(factory)
    mission = base.parent / name
    if mission.exists():
        return mission
    shutil.copytree(base, mission)
    ts = ros1_typestore()

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        if topic not in frames:
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        msg.header.frame_id = frames[topic]
        return topic, msgtype, ts.serialize_ros1(msg, msgtype)

    for bag in sorted(mission.glob("*.bag")):
        rewrite_bag(bag, convert)
    return mission
