"""The recording-source interface: one reader per input format, as rosbags' AnyReader sits
over its formats.

A *location* is what a user names as a recording: a local folder or file, or an `s3://`
prefix. A source never lists it itself: the caller lists it (`list_names` for a local location,
the object listing on S3) and every source judges the same names, so detection and identity
are the same code for local and remote recordings. A name is a POSIX path relative to the
location (`x.bag`, `data/.zgroup`); a folder's name ends with "/" (`images/cam0/`).

What a source answers (`RecordingSource`):

- `claims(names)`: does the listing (to `DETECT_DEPTH` levels) hold my format? Pure, cheap.
- `identity(names)`: the names, of the whole listing, whose (path, size, mtime_ns) key the
  recording's caches (a bag, a Zarr metadata file, an image folder): a change re-runs ingest.
- `ingest(...)`: the recording's index (`schemas.recording_index`) and its rectified images,
  through ingest's checks, gates and reject log (`pipeline.ingest.checks`).
- `iter_sweeps(...)`: the decoded sweeps of indexed rows (`file`, `position` as ingest wrote
  them), for the packets stage and the analyses.
- `inspect(path, began)`: what `m3gd inspect` reports for a recording in this format.
- `proof_data(path, ins, lidars)`: the few views `m3gd inspect`'s proof judges its decisions
  on (`pipeline.inspect.prove_read.ProofData`: sweeps, images and poses near a dozen times).

Time is int64 ns since the epoch everywhere; points are float32 metres in the LiDAR frame.
Adding a format: a module here with one class satisfying `RecordingSource` and one row in
`registry.SOURCES` (docs/architecture.md, "Recording sources").
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from pipeline.ingest.core.sinks import ImageSink
    from pipeline.ingest.index.ingest_result import IngestResult
    from pipeline.ingest.sources.pointcloud import Sweep
    from pipeline.inspect.model import Inspection
    from pipeline.inspect.prove_read import ProofData
    from schemas.config import IngestConfig

DETECT_DEPTH = 2
"""Levels of a listing `claims` sees (`x.bag`, `data/.zgroup`, `calibration/perspective.txt`):
detection never walks a large store."""


def name_order(name: str) -> tuple[str, ...]:
    """Sort key of a listing name: by path parts (as `sorted` orders `Path`s)."""
    return tuple(name.rstrip("/").split("/"))


def list_names(location: Path, depth: int | None = None) -> list[str]:
    """The names below a local `location` (a file: its own name), to `depth` levels (None: all),
    folders ending with "/", in `name_order`. Hidden names are kept: a source decides what it
    reads (a Zarr v2 store's metadata files start with a dot)."""
    if location.is_file():
        return [location.name]
    names: list[str] = []
    _walk(location, "", depth, names)
    return sorted(names, key=name_order)


def _walk(folder: Path, prefix: str, depth: int | None, out: list[str]) -> None:
    """Append the names below `folder` (as `prefix` + name) to `out`, `depth` levels deep."""
    if depth == 0:
        return
    with os.scandir(folder) as it:
        for e in it:
            if e.is_dir():
                out.append(f"{prefix}{e.name}/")
                _walk(Path(e.path), f"{prefix}{e.name}/", None if depth is None else depth - 1,
                      out)  # fmt: skip
            else:
                out.append(prefix + e.name)


class RecordingSource(Protocol):
    """One input format: detection, identity, ingest, sweep decoding and inspection.

    `name` is the format's name as `ingest.format` spells it (`rosbag`, `hf-zarr`) and as the
    ingest result's `input_format` begins. Methods are plain functions of paths and config,
    so they run the same in-process or on a Dask worker.
    """

    name: str
    expects: str  # what a location in this format holds, for errors ("Zarr store data/ ...")
    fixed_rig: bool  # the layout fixes LiDAR, poses and frames by file: inspect decides none

    def claims(self, names: Sequence[str]) -> bool:
        """True when a location's names (to `DETECT_DEPTH` levels) hold this format."""
        ...

    def identity(self, names: Sequence[str]) -> list[str]:
        """The names (of the whole listing of a claimed location) that identify the recording,
        in the order the cache key lists them."""
        ...

    def ingest(
        self,
        mission_dir: Path,
        out_dir: Path,
        cfg: IngestConfig,
        image_sink: ImageSink | None,
        recording: str,
    ) -> IngestResult:
        """Write `<out_dir>/index/<recording>/*.parquet`; hand each rectified image to
        `image_sink` in stamp order (`CameraImage`: (out_h, out_w, 3) uint8 RGB, int64 ns
        stamp, K_out (3, 3)). Faults in the data become rejects naming file, topic and
        stamp; a missing calibration chain raises MissingTransformError."""
        ...

    def iter_sweeps(self, mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
        """Decode indexed sweep rows in the given order: xyz (N, 3) float32 metres, intensity
        (N,), t_ns (N,) int64 ns per point."""
        ...

    def inspect(self, path: Path, began: float) -> Inspection:
        """`m3gd inspect` of a recording in this format; `began` is `time.perf_counter()` at
        the start of the inspection (its duration is reported)."""
        ...

    def proof_data(self, path: Path, ins: Inspection, lidars: list[str]) -> ProofData:
        """The views inspect's proof scores (`pipeline.inspect.prove_read`) of a recording
        inspected as `ins`: spread over the first of `lidars` (the reference), each LiDAR's
        sweep, each camera's rectified grey image and the poses near every view; what cannot
        be read is one line of `ProofData.problems`."""
        ...
