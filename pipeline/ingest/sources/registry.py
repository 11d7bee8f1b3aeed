"""The recording sources, one row each: which source reads a location, and by which name.

`SOURCES` is the one place a format is registered; ingest, the sweep reader, the input
identity, S3 staging and `m3gd inspect` all choose through `source_for` / `source_named`.
The first row that claims a listing reads it, so a specific layout (a Zarr store `data/`)
comes before the bag family, which also reads a folder of loose `.mcap` files. A location no
row claims goes to `FALLBACK`, whose reader names the files it skipped and why.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from pipeline.ingest.sources.base import DETECT_DEPTH, RecordingSource, list_names
from pipeline.ingest.sources.hf.source import HfSource
from pipeline.ingest.sources.kitti360 import Kitti360Source
from pipeline.ingest.sources.rosbag import RosbagSource
from schemas.errors import DataError

SOURCES: tuple[RecordingSource, ...] = (
    HfSource(),  # GrandTour's Hugging Face layout: a Zarr store data/ + images/<group>/
    Kitti360Source(),  # KITTI-360 raw: calibration/, data_2d_raw/, data_3d_raw/, data_poses/
    RosbagSource(),  # ROS1 .bag, rosbag2 folders, loose .mcap files (profiles ros1, ros2)
)

FALLBACK = "rosbag"
"""The source of a location no row claims: its error names what it skipped and why."""


def source_named(name: str) -> RecordingSource:
    """The source registered as `name`; DataError listing the registered names otherwise."""
    for src in SOURCES:
        if src.name == name:
            return src
    raise DataError(f"unknown input format {name!r}; one of "
                    f"{', '.join(s.name for s in SOURCES)}")  # fmt: skip


def claiming(names: Sequence[str]) -> RecordingSource:
    """The first source whose `claims` accepts the listing names; `FALLBACK` when none does."""
    return next((s for s in SOURCES if s.claims(names)), source_named(FALLBACK))


def source_for(location: Path) -> RecordingSource:
    """The source that reads a local folder or file (listed to `DETECT_DEPTH` levels)."""
    return claiming(list_names(location, DETECT_DEPTH) if location.exists() else [])


def resolve(location: Path, configured: str) -> tuple[RecordingSource, bool]:
    """(source, detected?) for a mission folder: `configured` (`ingest.format`) unless "auto".

    DataError when the configured source does not claim the folder but another one does (a
    rosbag source asked to read a folder without bags keeps its own error, naming the skipped
    files)."""
    found = source_for(location)
    if configured == "auto":
        return found, True
    src = source_named(configured)
    if src is not found and src.name != FALLBACK:
        raise DataError(f"{location}: ingest.format is {src.name} but there is no "
                        f"{src.expects} (found: {found.name})")  # fmt: skip
    return src, False
