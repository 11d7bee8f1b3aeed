"""Indexed sweeps read back from a mission, whatever its format: bags
(`pipeline.ingest.sources.pointcloud`) or the Hugging Face layout
(`pipeline.ingest.sources.hf.points`)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from pipeline.ingest.sources.bags import BagFile, bag_path
from pipeline.ingest.sources.hf.points import iter_hf_sweeps
from pipeline.ingest.sources.hf.store import detect_format
from pipeline.ingest.sources.pointcloud import Sweep, find_sweep


def load_sweep(mission_dir: Path, sweep_row: Mapping[str, Any]) -> Sweep:
    """Decode one indexed sweep: xyz (N, 3) float32, intensity (N,), t_ns (N,) int64, counts."""
    return next(iter_sweeps(mission_dir, [sweep_row]))


def iter_sweeps(mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
    """Decode indexed sweeps in the given order, opening each bag file once per run of rows.

    A mission in the Hugging Face layout is read from its Zarr store instead (`ingest.hf`).
    """
    if detect_format(mission_dir) == "hf-zarr":
        yield from iter_hf_sweeps(mission_dir, rows)
        return
    bag: BagFile | None = None
    try:
        for row in rows:
            file = str(row["file"])
            if bag is None or bag.name != file:
                if bag is not None:
                    bag.close()
                bag = BagFile(bag_path(mission_dir, file), mission_dir)
            yield find_sweep(bag, row)
    finally:
        if bag is not None:
            bag.close()
