"""Merge per-shard statistics into tables partitioned by recording (hive layout).

`out/stats/<table>/recording=<rec>/part-0.parquet`; the merge concatenates the
shard parts in (camera, frame) order, so it is exact and deterministic.
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc

from packets.running_stats import ChannelStats, merge_all
from pipeline.stats.rows import PARTS_DIR
from schemas.atomic_io import write_text_atomic
from schemas.errors import MissingInputError
from schemas.layout import OutputLayout
from schemas.tables import CELL_STATS, VIEW_STATS, read_table, write_table

TABLES = {"view_stats": VIEW_STATS, "cell_stats": CELL_STATS}
LATENT_PARTS = "latent_parts"


def merge_recording(output_dir: Path, recording: str) -> dict[str, int]:
    """Merge the shard parts of one recording; return rows per table."""
    parts = OutputLayout(output_dir).stats / PARTS_DIR / recording
    rows = {}
    for name, schema in TABLES.items():
        files = sorted(parts.glob(f"{name}-*.parquet"))
        tables = [read_table(f, schema) for f in files]
        merged = pa.concat_tables(tables) if tables else schema.empty_table()
        keys = [("camera", "ascending"), ("frame", "ascending")]
        if name == "cell_stats":
            keys += [("row", "ascending"), ("col", "ascending")]
        merged = merged.take(pc.sort_indices(merged, sort_keys=keys))
        out = OutputLayout(output_dir).stats / name / f"recording={recording}" / "part-0.parquet"
        write_table(merged, schema, out)
        rows[name] = merged.num_rows
    return rows


def latent_part_path(output_dir: Path, recording: str, camera: str, shard: int) -> Path:
    """Where the encode stage stores one shard's latent channel statistics."""
    return OutputLayout(output_dir).stats / LATENT_PARTS / recording / f"{camera}-{shard:06d}.json"


def write_latent_part(path: Path, stats: ChannelStats) -> None:
    """Atomically write one shard's channel statistics."""
    write_text_atomic(path, json.dumps(stats.to_dict()))


def latent_part_files(output_dir: Path) -> list[Path]:
    """Every shard's latent statistics file written by the encode stage, sorted."""
    return sorted((OutputLayout(output_dir).stats / LATENT_PARTS).glob("*/*.json"))


def merge_latent_stats(output_dir: Path) -> ChannelStats:
    """Tree-merge every shard's latent statistics (exact parallel-variance merge)."""
    files = latent_part_files(output_dir)
    if not files:
        raise MissingInputError(f"{OutputLayout(output_dir).stats / LATENT_PARTS}: no latent "
                                "statistics")
    return merge_all([ChannelStats.from_dict(json.loads(f.read_text())) for f in files])
