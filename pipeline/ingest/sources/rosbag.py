"""The ROS bag family as one recording source: ROS1 `.bag` files, rosbag2 folders (sqlite3 or
MCAP storage) and loose `.mcap` files (profiles `ros1` and `ros2`), read by `bags.BagFile`.

A location is claimed when it is a bag file, holds one at its top level, is a rosbag2 folder
(`metadata.yaml`) or holds rosbag2 folders one level down. Ingest streams every bag once
through the checks, gates and reject log (`pipeline.ingest.core.bag_pass`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.ingest.sources.bags import BAG_SUFFIXES, BagFile, bag_path
from pipeline.ingest.sources.base import name_order
from pipeline.ingest.sources.pointcloud import Sweep, find_sweep
from schemas.config import IngestConfig

if TYPE_CHECKING:
    from pipeline.ingest.core.sinks import ImageSink
    from pipeline.ingest.index.ingest_result import IngestResult
    from pipeline.inspect.model import Inspection
    from pipeline.inspect.prove_read import ProofData

ROSBAG2_META = "metadata.yaml"


def _top(name: str) -> bool:
    """A name at the location's top level (not inside a folder)."""
    return "/" not in name


class RosbagSource:
    """ROS1 bags, rosbag2 folders and loose MCAP files (`ingest.format: rosbag`)."""

    name = "rosbag"
    expects = "ROS1 .bag file, .mcap file or ROS2 bag folder (metadata.yaml)"
    fixed_rig = False

    def claims(self, names: Sequence[str]) -> bool:
        """A top-level `.bag`/`.mcap` file, a `metadata.yaml` here or one folder down."""
        return any((_top(n) and n.endswith(BAG_SUFFIXES)) or n == ROSBAG2_META
                   or (n.count("/") == 1 and n.endswith("/" + ROSBAG2_META)) for n in names)

    def identity(self, names: Sequence[str]) -> list[str]:
        """Top-level `.bag` files, then top-level `.mcap` files, each in name order."""
        return [n for suffix in BAG_SUFFIXES
                for n in sorted((n for n in names if _top(n) and n.endswith(suffix)),
                                key=name_order)]  # fmt: skip

    def ingest(self, mission_dir: Path, out_dir: Path, cfg: IngestConfig,
               image_sink: ImageSink | None, recording: str) -> IngestResult:  # fmt: skip
        """Stream every bag of the mission into its index (`core.bag_pass.ingest_bags`)."""
        from pipeline.ingest.core.bag_pass import ingest_bags

        return ingest_bags(mission_dir, out_dir, cfg, image_sink, recording)

    def iter_sweeps(self, mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
        """Decode indexed sweeps, opening each bag file once per run of rows of that file."""
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

    def inspect(self, path: Path, began: float) -> Inspection:
        """`m3gd inspect` of a bag file, a rosbag2 folder or a mission folder of bags."""
        from pipeline.inspect.scan import inspect_bags

        return inspect_bags(path, began)

    def proof_data(self, path: Path, ins: Inspection, lidars: list[str]) -> ProofData:
        """The proof's views of the recording (`pipeline.inspect.prove_read.bag_proof_data`)."""
        from pipeline.inspect.prove_read import bag_proof_data

        return bag_proof_data(path, ins, lidars)
