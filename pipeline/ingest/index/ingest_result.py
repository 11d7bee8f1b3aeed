"""What ingest writes for a recording, whatever its format: the result counts and the streaming
writers of its index tables (images, sweeps, odometry, rejects, damage)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa

from pipeline.ingest.checks.rejects import RejectLog
from pipeline.ingest.core.stream import Writers
from schemas.recording_index import (
    CHECKS,
    DAMAGE,
    IMAGES,
    ODOMETRY,
    SWEEPS,
    IndexTableWriter,
    table_path,
    write_index_table,
)


@dataclass
class IngestResult:
    """What ingest wrote: counts per table, rejects by reason code, and timing."""

    recording: str
    index_dir: Path
    images: dict[str, int] = field(default_factory=dict)
    sweeps: int = 0
    odometry: int = 0
    rejects: dict[str, int] = field(default_factory=dict)
    unaccounted: dict[tuple[str, str], int] = field(default_factory=dict)
    decode_reduction: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)
    input_format: str = "rosbag"
    checks: list[dict[str, object]] = field(default_factory=list)
    """Checks-table rows: which plausibility check ran on which topic, its state and counts."""


def write_checks(idx: Path, rows: list[dict[str, object]]) -> None:
    """The checks table of a recording (`schemas.recording_index.CHECKS`)."""
    write_index_table(pa.Table.from_pylist(rows, schema=CHECKS), CHECKS, table_path(idx, "checks"))


@contextmanager
def index_writers(idx: Path) -> Iterator[Writers]:
    """Streaming writers of the images, sweeps, odometry, rejects and damage tables: moved into
    place
    when the block ends, their temp files deleted when it raises."""
    out = Writers(
        images=IndexTableWriter(table_path(idx, "images"), IMAGES),
        sweeps=IndexTableWriter(table_path(idx, "sweeps"), SWEEPS),
        odometry=IndexTableWriter(table_path(idx, "odometry"), ODOMETRY),
        rejects=RejectLog.open(table_path(idx, "rejects")),
        damage=IndexTableWriter(table_path(idx, "damage"), DAMAGE),
    )
    try:
        yield out
    except BaseException:
        for w in (out.images, out.sweeps, out.odometry, out.damage, out.rejects.writer):
            w.abort()
        raise
    for w in (out.images, out.sweeps, out.odometry, out.damage):
        w.close()
    out.rejects.close()
