"""`ingest_recording`: a mission folder to its recording index (and rectified images to a sink).

A plain function of paths and config, so it runs the same in-process or on a Dask worker.
Output: `<out_dir>/index/<recording>/{images,sweeps,odometry,calibration,rejects}.parquet`
(schemas in `schemas.recording_index`). Peak memory does not grow with the recording length:
every bag is streamed once and index rows are flushed in batches.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.ingest.core.stream import ImageSink
from pipeline.ingest.index.ingest_result import IngestResult
from pipeline.ingest.sources.registry import resolve
from schemas.config import IngestConfig


def recording_name(mission_dir: Path) -> str:
    """The recording name: the mission folder's name."""
    return mission_dir.resolve().name


def ingest_recording(
    mission_dir: Path,
    out_dir: Path,
    cfg: IngestConfig,
    image_sink: ImageSink | None = None,
    recording: str | None = None,
) -> IngestResult:
    """Index one mission folder; hand each rectified image to `image_sink` in stamp order.

    `recording` names the output (default: the mission folder's name). The folder is read by
    the source `cfg.format` names, or the one that claims it (`sources.registry`): bags, or
    the Hugging Face layout (a Zarr store `data/`), into the same index.
    Raises MissingTransformError (naming the missing chain) when a configured camera or the
    LiDAR is not connected to the base frame; recoverable faults become rejects.
    """
    rec = recording or recording_name(mission_dir)
    source, detected = resolve(mission_dir, cfg.format)
    result = source.ingest(mission_dir, out_dir, cfg, image_sink, rec)
    result.input_format += ", detected" if detected else ", set by ingest.format"
    return result
