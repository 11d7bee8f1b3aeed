"""Indexed sweeps read back from a mission, whatever its format, through its recording source
(`pipeline.ingest.sources.registry`)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from pipeline.ingest.sources.pointcloud import Sweep
from pipeline.ingest.sources.registry import source_for


def load_sweep(mission_dir: Path, sweep_row: Mapping[str, Any]) -> Sweep:
    """Decode one indexed sweep: xyz (N, 3) float32, intensity (N,), t_ns (N,) int64, counts."""
    return next(iter_sweeps(mission_dir, [sweep_row]))


def iter_sweeps(mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
    """Decode indexed sweeps in the given order, through the source that reads the mission
    (`sources.registry.source_for`): a bag file is opened once per run of its rows."""
    return source_for(mission_dir).iter_sweeps(mission_dir, rows)
