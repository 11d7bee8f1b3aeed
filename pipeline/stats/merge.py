"""Merge per-shard statistics into one file per recording and table.

`out/stats/<table>/<rec>.parquet` (`schemas.tables.STATS_LAYOUT_VERSION`: the `recording`
column names the recording, no hive folder); the merge concatenates the shard parts in
(camera, frame) order, so it is exact and deterministic.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc

from packets.running_stats import ChannelStats, merge_all
from pipeline.stats.rows import PARTS_DIR
from schemas.atomic_io import checksum_path, write_text_atomic
from schemas.errors import DataError, MissingInputError
from schemas.layout import OutputLayout
from schemas.tables import CELL_STATS, VIEW_STATS, read_table, write_recording_part

TABLES = {"view_stats": VIEW_STATS, "cell_stats": CELL_STATS}
LATENT_PARTS = "latent_parts"
LATENT_PART_VERSION = 2
"""2: each part names what it was computed from (`LatentPart`); 1 (no `version` key): the
statistics only (refused: its shard may belong to another layout)."""


def merge_recording(output_dir: Path, recording: str,
                    shards: dict[str, int] | None = None) -> dict[str, int]:
    """Merge the shard parts of one recording; return rows per table.

    shards: camera -> shard count of the cache now: exactly those parts are merged (one
    missing is refused in one line) and parts of any other camera or shard (an earlier
    layout's) are removed; None: every part there.
    """
    parts = OutputLayout(output_dir).stats / PARTS_DIR / recording
    if shards is not None:
        _keep_only(parts, {f"{n}-{c}-{k:06d}.parquet" for c, count in shards.items()
                           for k in range(count) for n in TABLES})
    rows = {}
    for name, schema in TABLES.items():
        files = sorted(parts.glob(f"{name}-*.parquet"))
        tables = [read_table(f, schema) for f in files]
        merged = pa.concat_tables(tables) if tables else schema.empty_table()
        keys = [("camera", "ascending"), ("frame", "ascending")]
        if name == "cell_stats":
            keys += [("row", "ascending"), ("col", "ascending")]
        merged = merged.take(pc.sort_indices(merged, sort_keys=keys))
        write_recording_part(merged, schema, OutputLayout(output_dir).stats / name, recording)
        rows[name] = merged.num_rows
    return rows


def _keep_only(folder: Path, names: set[str]) -> list[Path]:
    """Remove the files of `folder` not named in `names` (with their checksum sidecars; hidden
    files are not parts); refuse (one line) when one named is absent. Returns the removed
    files."""
    have = ({p.name: p for p in folder.glob("*") if p.is_file() and not p.name.startswith(".")}
            if folder.is_dir() else {})
    absent = sorted(names - set(have))
    if absent:
        raise MissingInputError(f"{folder / absent[0]}: statistics part missing ({len(absent)} "
                                "in all); the packets stage of this shard did not "
                                "finish: run m3gd run again")
    removed = [have[n] for n in sorted(set(have) - names)]
    for path in removed:
        path.unlink()
        checksum_path(path).unlink(missing_ok=True)
    return removed


@dataclass(frozen=True)
class LatentPart:
    """What one shard's latent statistics were computed from: its group `<rec>/<camera>`,
    shard, view range [start, stop), the valid views encoded and the encode item's cache key
    (the one its done-mark carries)."""

    group: str
    shard: int
    views: tuple[int, int]
    valid_views: int
    cache_key: str

    def to_dict(self) -> dict[str, object]:
        """JSON-compatible fields."""
        return {"group": self.group, "shard": self.shard, "views": list(self.views),
                "valid_views": self.valid_views, "cache_key": self.cache_key}


def latent_part_path(output_dir: Path, recording: str, camera: str, shard: int) -> Path:
    """Where the encode stage stores one shard's latent channel statistics."""
    return OutputLayout(output_dir).stats / LATENT_PARTS / recording / f"{camera}-{shard:06d}.json"


def write_latent_part(path: Path, stats: ChannelStats, part: LatentPart) -> None:
    """Atomically write one shard's channel statistics with what they were computed from."""
    body = {"version": LATENT_PART_VERSION, **part.to_dict(), "stats": stats.to_dict()}
    write_text_atomic(path, json.dumps(body), checksum=True)


def read_latent_part(path: Path, want: LatentPart) -> ChannelStats:
    """The statistics of part file `path`, refused in one line unless they were computed from
    `want` (same group, shard, views, valid views and encode cache key)."""
    raw = json.loads(path.read_text())
    got = raw if raw.get("version") == LATENT_PART_VERSION else {}
    expected = want.to_dict()
    fields = {k: got.get(k) for k in expected}
    if fields != expected:
        why = ("an earlier format" if not got else
               next(f"{k} {fields[k]!r}, the cache has {expected[k]!r}" for k in fields
                    if fields[k] != expected[k]))
        raise DataError(f"{path}: latent statistics of another cache layout ({why}); "
                        "m3gd run --force encode recomputes them")
    return ChannelStats.from_dict(raw["stats"])


def _part_path(output_dir: Path, part: LatentPart) -> Path:
    """`latent_part_path` of a part named by its group `<recording>/<camera>`."""
    recording, camera = part.group.split("/")
    return latent_part_path(output_dir, recording, camera, part.shard)


def merge_latent_parts(output_dir: Path, parts: list[LatentPart]
                       ) -> tuple[ChannelStats, dict[str, int], list[Path]]:
    """Merge exactly the latent statistics of `parts` (the cache's shards now): (merged,
    valid views per group from the parts, removed leftover files of other shards or groups).
    A part that is absent or computed from something else is refused in one line."""
    root = OutputLayout(output_dir).stats / LATENT_PARTS
    paths = {_part_path(output_dir, p): p for p in parts}
    removed = [f for f in latent_part_files(output_dir) if f not in paths]
    for f in removed:
        f.unlink()
        checksum_path(f).unlink(missing_ok=True)
    if not parts:
        raise MissingInputError(f"{root}: no latent statistics")
    for path in paths:
        if not path.exists():
            raise MissingInputError(f"{path}: latent statistics part missing; the encode "
                                    "stage of this shard did not finish: run m3gd run again")
    stats = merge_all([read_latent_part(path, p) for path, p in paths.items()])
    groups: dict[str, int] = {}
    for p in parts:
        groups[p.group] = groups.get(p.group, 0) + p.valid_views
    return stats, groups, removed


def latent_part_files(output_dir: Path) -> list[Path]:
    """Every shard's latent statistics file written by the encode stage, sorted."""
    return sorted((OutputLayout(output_dir).stats / LATENT_PARTS).glob("*/*.json"))
