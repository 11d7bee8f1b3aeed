"""`inspect_recording`: the whole inspection of a recording, by the source that reads it.

The source chosen by the registry inspects its location (`RecordingSource.inspect`; the bag
family: `scan.inspect_bags`). This module sits above the sources; none of them imports it.
"""

from __future__ import annotations

import time
from pathlib import Path

from pipeline.ingest.sources.registry import source_for
from pipeline.inspect.model import Inspection
from schemas.errors import MissingInputError


def inspect_recording(path: Path) -> Inspection:
    """Inspect a `.bag` or `.mcap` file, a ROS2 bag folder, a mission folder of bags or an HF
    mission.

    MissingInputError (naming `path`) when there is nothing to read; DataError for a bag that
    cannot be opened.
    """
    began = time.perf_counter()
    if not path.exists():
        raise MissingInputError(f"{path}: no such file or folder")
    return source_for(path).inspect(path, began)
