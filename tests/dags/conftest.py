"""Shared fixtures of the DAG tests: two tiny synthetic recordings and a tiny config."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from schemas.config import M3GDConfig, SynthConfig, parse_config

SCENES = ("corridor", "warehouse")


def synth_config() -> SynthConfig:
    """A very small synthetic recording (seconds, pixels and points cut for test speed)."""
    return SynthConfig(seconds=2.0, image_width=192, image_height=128, points_per_sweep=2048)


@pytest.fixture(scope="session")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Two synthetic missions, generated once per test session."""
    from pipeline.synth.api import synthesize

    base = tmp_path_factory.mktemp("recordings")
    return [Path(str(synthesize(base, synth_config(), scene, mission=f"t_{scene}").mission_dir))
            for scene in SCENES]


def tiny_raw(out: Path, recordings: list[Path]) -> dict[str, Any]:
    """Raw config mapping of a tiny run over `recordings` into `out`."""
    return {
        "output_dir": str(out),
        "ingest": {"recordings": [str(r) for r in recordings], "out_height": 112,
                   "out_width": 168},
        "encoders": {"image_channels": 588, "point_channels": 16},
        "cache": {"shard_views": 8},
        "dag": {"retries": 1, "workers": 2},
        "clips": {"eval_clips_per_recording": 10},
    }


def tiny_config(out: Path, recordings: list[Path]) -> M3GDConfig:
    """The tiny config as a validated model."""
    return parse_config(tiny_raw(out, recordings))


def write_config(path: Path, out: Path, recordings: list[Path]) -> Path:
    """The tiny config as a YAML file."""
    path.write_text(yaml.safe_dump(tiny_raw(out, recordings)))
    return path
