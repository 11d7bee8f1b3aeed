"""GrandTour's Hugging Face layout as a recording source: a Zarr store `data/` (v2 `.zgroup` or
v3 `zarr.json`, one group per topic) beside `images/<group>/NNNNNN.jpeg`.

Ingest reads each topic group row by row through the same stamp gates, checks and reject log
as bags (`read.ingest_hf`); sweeps are read back from the store (`points.iter_hf_sweeps`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.ingest.sources.base import name_order
from pipeline.ingest.sources.hf.store import DATA_DIR, IMAGES_DIR
from pipeline.ingest.sources.rosbag import RosbagSource
from schemas.config import IngestConfig

if TYPE_CHECKING:
    from pipeline.ingest.core.sinks import ImageSink
    from pipeline.ingest.index.ingest_result import IngestResult
    from pipeline.ingest.sources.pointcloud import Sweep
    from pipeline.inspect.model import Inspection
    from pipeline.inspect.prove_read import ProofData

GROUP_FILES = (f"{DATA_DIR}/.zgroup", f"{DATA_DIR}/zarr.json")
"""The store's root metadata, Zarr v2 or v3: the layout's mark."""
META_NAMES = (".zarray", ".zattrs", "zarr.json")
"""Zarr metadata files whose identity keys the caches (chunks change with them)."""


class HfSource:
    """A mission in the Hugging Face layout (`ingest.format: hf-zarr`)."""

    name = "hf-zarr"
    expects = f"Zarr store {DATA_DIR} (no .zgroup or zarr.json)"
    fixed_rig = False

    def claims(self, names: Sequence[str]) -> bool:
        """The store's root metadata `data/.zgroup` or `data/zarr.json` is listed."""
        return any(n in GROUP_FILES for n in names)

    def identity(self, names: Sequence[str]) -> list[str]:
        """Bags beside the store (none in a release), every Zarr metadata file of `data/` and
        every image folder `images/<group>/` (its mtime changes with its files)."""
        meta = [n for n in names if n.startswith(DATA_DIR + "/")
                and n.rsplit("/", 1)[-1] in META_NAMES]  # fmt: skip
        images = [n for n in names if n.startswith(IMAGES_DIR + "/") and n.endswith("/")
                  and n.count("/") == 2]  # fmt: skip
        return (RosbagSource().identity(names) + sorted(meta, key=name_order)
                + sorted(images, key=name_order))  # fmt: skip

    def ingest(self, mission_dir: Path, out_dir: Path, cfg: IngestConfig,
               image_sink: ImageSink | None, recording: str) -> IngestResult:  # fmt: skip
        """Index the mission from its store and JPEG folders (`read.ingest_hf`)."""
        from pipeline.ingest.sources.hf.read import ingest_hf

        return ingest_hf(mission_dir, out_dir, cfg, image_sink, recording)

    def iter_sweeps(self, mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
        """Decode indexed sweeps from the store (topic = group, ordinal = row)."""
        from pipeline.ingest.sources.hf.points import iter_hf_sweeps

        return iter_hf_sweeps(mission_dir, rows)

    def inspect(self, path: Path, began: float) -> Inspection:
        """`m3gd inspect` of the mission's store and image folders."""
        from pipeline.inspect.hf import inspect_hf

        return inspect_hf(path, began)

    def proof_data(self, path: Path, ins: Inspection, lidars: list[str]) -> ProofData:
        """The proof's views of the recording (`pipeline.inspect.prove_hf.hf_proof_data`)."""
        from pipeline.inspect.prove_hf import hf_proof_data

        return hf_proof_data(path, ins, lidars)
