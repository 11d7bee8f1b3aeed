"""The same small synthetic recording in both formats, made once per test session."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

from pipeline.synth.api import synthesize
from schemas.config import IngestConfig, SynthConfig
from tests.pipeline.synthkit import RECORDINGS, SMALL

INGEST = IngestConfig(out_height=112, out_width=168)


def mission(factory: pytest.TempPathFactory, name: str, fmt: str, version: int = 2) -> Path:
    """Mission `name` (a synthkit recording: 'clean', 'faulty', ...) written as `fmt`."""
    root = factory.getbasetemp() / "hf_kit" / f"{fmt}_v{version}"
    out = root / name
    if not (out / "groundtruth" / "faults.json").exists():
        extra: dict[str, Any] = {**SMALL, **RECORDINGS[name]}
        cfg = SynthConfig(seed=3, scenes=["corridor"], format=fmt, hf_zarr_version=version,
                          **extra)  # fmt: skip
        synthesize(root, cfg, "corridor", name)
    return out


def copy_of(factory: pytest.TempPathFactory, name: str, tmp: Path) -> Path:
    """A private copy of HF mission `name` that a test may damage."""
    dst = tmp / name
    shutil.copytree(mission(factory, name, "hf-zarr"), dst)
    return dst
