"""The KITTI-360 raw layout as a recording source (`kitti360_layout`: where its files are and
its calibration; `kitti360_read`: its pass through the ingest core; `kitti360_inspect`)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.ingest.sources.kitti360_layout import (
    FORMAT,
    Kitti360Layout,
    camera_folders,
    identifies,
)
from schemas.config import IngestConfig

if TYPE_CHECKING:
    from pipeline.ingest.core.sinks import ImageSink
    from pipeline.ingest.index.ingest_result import IngestResult
    from pipeline.ingest.sources.pointcloud import Sweep
    from pipeline.inspect.model import Inspection
    from pipeline.inspect.prove_read import ProofData

__all__ = ["Kitti360Layout", "Kitti360Source", "camera_folders"]


class Kitti360Source:
    """The KITTI-360 raw layout behind `base.RecordingSource` (one sequence per root)."""

    name = FORMAT
    expects = "KITTI-360 layout (calibration/perspective.txt and a data_3d_raw/<seq>/ folder)"
    fixed_rig = True

    def claims(self, names: Sequence[str]) -> bool:
        """`calibration/perspective.txt` and a sequence folder `data_3d_raw/<seq>/` (2 levels)."""
        return "calibration/perspective.txt" in names and any(
            n.startswith("data_3d_raw/") and n.endswith("/") and n.count("/") == 2
            for n in names)  # fmt: skip

    def identity(self, names: Sequence[str]) -> list[str]:
        """Calibration files, every timestamps.txt, poses.txt, cam0_to_world.txt and the data
        folders (`data_rect/`, `data/`), in listing order."""
        return [n for n in names if identifies(n)]

    def ingest(self, mission_dir: Path, out_dir: Path, cfg: IngestConfig,
               image_sink: ImageSink | None, recording: str) -> IngestResult:  # fmt: skip
        """The recording index (`kitti360_read.ingest_kitti360`)."""
        from pipeline.ingest.sources.kitti360_read import ingest_kitti360

        return ingest_kitti360(mission_dir, out_dir, cfg, image_sink, recording)

    def iter_sweeps(self, mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
        """Decoded indexed sweeps; every point at its sweep's stamp."""
        from pipeline.ingest.sources.kitti360_read import iter_kitti360_sweeps

        return iter_kitti360_sweeps(mission_dir, rows)

    def inspect(self, path: Path, began: float) -> Inspection:
        """`m3gd inspect` of a KITTI-360 root (`kitti360_inspect`)."""
        from pipeline.ingest.sources.kitti360_inspect import inspect_kitti360

        return inspect_kitti360(path, began)

    def proof_data(self, path: Path, ins: Inspection, lidars: list[str]) -> ProofData:
        """The proof's views of the root (`pipeline.inspect.prove_kitti360`)."""
        from pipeline.inspect.prove_kitti360 import kitti360_proof_data

        return kitti360_proof_data(path, ins, lidars)
