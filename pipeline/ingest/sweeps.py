"""Load indexed sweeps back from their bags (only the ones a stage needs).

A sweep row of the index names its bag file (relative to the mission folder), topic, log time
and header stamp; the message is found by seeking to its log time and matching the stamp.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from pipeline.ingest.bags import BagFile, stamp_ns
from pipeline.ingest.pointcloud import Sweep, decode_cloud


def load_sweep(mission_dir: Path, sweep_row: Mapping[str, Any]) -> Sweep:
    """Decode one indexed sweep: xyz (N, 3) float32, intensity (N,), t_ns (N,) int64, counts."""
    return next(iter_sweeps(mission_dir, [sweep_row]))


def iter_sweeps(mission_dir: Path, rows: Iterable[Mapping[str, Any]]) -> Iterator[Sweep]:
    """Decode indexed sweeps in the given order, opening each bag file once per run of rows."""
    bag: BagFile | None = None
    try:
        for row in rows:
            file = str(row["file"])
            if bag is None or bag.name != file:
                if bag is not None:
                    bag.close()
                bag = BagFile(mission_dir / file, mission_dir)
            yield _find(bag, row)
    finally:
        if bag is not None:
            bag.close()


def _find(bag: BagFile, row: Mapping[str, Any]) -> Sweep:
    """The sweep of `row` in an open bag; LookupError naming it when absent."""
    topic, log_ns, stamp = str(row["topic"]), int(row["bag_time_ns"]), int(row["stamp_ns"])
    for msg in bag.messages([topic], start=log_ns):
        if msg.bag_time_ns > log_ns:
            break
        obj = bag.deserialize(msg)
        if stamp_ns(obj) == stamp:
            return decode_cloud(obj, stamp)
    raise LookupError(
        f"{bag.name}: no {topic} message with log time {log_ns} ns and stamp {stamp} ns"
    )
