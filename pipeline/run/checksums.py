"""Checksum sidecars of the tables and metadata files of an output: which is damaged, who
writes it, and forgetting what the next run must redo.

Every table and metadata file the stages write outside the cache chunks (index tables,
statistics parts and tables, the clip index, the cache groups' `zarr.json`, the run
manifest) is written with a checksum sidecar (`schemas.atomic_io.checksum_path`: size,
CRC32C, and the stage item that wrote it). `verify_files` checks each against its file and
names a damaged, cut or missing one with that stage item; `forget_files` makes the next run
redo the item and, within what it redoes, every stage that depends on it (their done-marks
and manifest items). `m3gd verify` and every local `m3gd run` (before planning) do both.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from pipeline.run.keys import ItemKey
from schemas.atomic_io import CHECKSUM_SUFFIX, check_file, checksum_path, file_of, read_sidecar
from schemas.layout import (
    CACHE_DIRNAME,
    DONE_DIRNAME,
    INDEX_DIRNAME,
    MANIFEST_FILENAME,
    STATS_DIRNAME,
)
from schemas.manifest import RunManifest
from schemas.stages import STAGE_TABLE, writer_of_table

GROUP_WRITER = next(s.name for s in STAGE_TABLE if s.arrays)
"""The stage that creates the cache groups (and writes their `zarr.json` first; later
stages add attributes): the first stage of the table that writes arrays."""

Dependants = Callable[[str], Sequence[str]]
"""stage -> that stage and every stage that depends on it, transitively (the stage graph's
`downstream_of`)."""


@dataclass(frozen=True)
class DamagedFile:
    """A table or metadata file that does not match its checksum sidecar (or is gone), with
    the stage and item that write it (None: not written by a stage item)."""

    path: Path
    detail: str
    stage: str | None
    item: str | None

    def line(self) -> str:
        """One line naming the file, what is wrong and what rewrites it."""
        by = (f"written by {self.stage} {self.item}, redone by the next run" if self.stage
              else "not written by a stage: rerun the command that wrote it")
        return f"{self.path}: {self.detail}; {by}"


@dataclass(frozen=True)
class Scope:
    """What a redo covers: a recording, or one camera's shard of it (None: all)."""

    recording: str
    camera: str | None = None
    shard: int | None = None

    def covers(self, key: str) -> bool:
        """Whether the formatted item key `key` overlaps this scope (cross items always)."""
        item = ItemKey.parse(key)
        if item.is_cross:
            return True
        return item.recording == self.recording and (
            None in (item.camera, self.camera) or item.camera == self.camera) and (
            None in (item.shard, self.shard) or item.shard == self.shard)


def unmark(cache: Path, stage: str, scope: Scope) -> None:
    """Remove `stage`'s done-marks inside `scope`."""
    cams = cache.parent / DONE_DIRNAME / scope.recording
    shard = "*" if scope.shard is None else f"{scope.shard:06d}"
    for mark in cams.glob(f"{scope.camera or '*'}/{stage}.{shard}.json"):
        mark.unlink(missing_ok=True)


def guarded_files(out_dir: Path) -> list[Path]:
    """Every file of the output with a checksum sidecar (the run manifest excepted): the
    index tables, statistics, the clip index and the cache groups' metadata (the chunks
    carry their own)."""
    sidecars = [*out_dir.glob(f".*{CHECKSUM_SUFFIX}"),
                *(out_dir / DONE_DIRNAME).glob(f"*/*/.zarr.json{CHECKSUM_SUFFIX}"),
                *(out_dir / DONE_DIRNAME).glob(f".zarr.json{CHECKSUM_SUFFIX}")]
    for folder in (INDEX_DIRNAME, STATS_DIRNAME):
        sidecars += (out_dir / folder).rglob(f".*{CHECKSUM_SUFFIX}")
    files = sorted({file_of(s) for s in sidecars})
    return [f for f in files if f != out_dir / MANIFEST_FILENAME]


def writer_of(out_dir: Path, path: Path) -> tuple[str, str] | None:
    """(stage, formatted item key) that writes `path`: its sidecar's record; a cache group's
    `zarr.json` by the GROUP_WRITER item of its recording; an index table, when its sidecar
    cannot be read, by the stage the stage table says writes it (by its name)."""
    rel = path.relative_to(out_dir).parts
    if rel[0] == CACHE_DIRNAME and len(rel) == 4:
        return GROUP_WRITER, ItemKey(rel[1]).format()
    found = read_sidecar(checksum_path(path))
    if found is not None and found.stage and found.item:
        return found.stage, found.item
    spec = writer_of_table(Path(rel[-1]).stem) if rel[0] == INDEX_DIRNAME and len(rel) == 3 \
        else None
    return None if spec is None else (spec.name, rel[1])


def verify_files(out_dir: Path) -> tuple[int, list[DamagedFile]]:
    """(files checked, damaged ones): each guarded file against its sidecar."""
    damaged = []
    files = guarded_files(out_dir)
    for path in files:
        why = check_file(path)
        if why is not None:
            owner = writer_of(out_dir, path)
            damaged.append(DamagedFile(path, why, *(owner or (None, None))))
    return len(files), damaged


def forget_files(cache: Path, manifest: RunManifest | None, damaged: Sequence[DamagedFile],
                 dependants: Dependants) -> list[str]:
    """Make the next run redo the stage item that writes each damaged file and, within what
    it redoes, every stage that depends on it (their done-marks and manifest items, as
    `invalidate`); returns what was forgotten, one '<stage> <item>' per manifest entry."""
    forgotten: list[str] = []
    for file in damaged:
        if file.stage is None or file.item is None:
            continue
        key = ItemKey.parse(file.item)
        scope = None if key.is_cross else Scope(key.require_recording(), key.camera, key.shard)
        for hit in dependants(file.stage):
            if scope is not None:
                unmark(cache, hit, scope)
            items = manifest.stages[hit].items if manifest and hit in manifest.stages else {}
            for k in [k for k in items if (scope.covers(k) if scope is not None
                                           else hit != file.stage or k == file.item)]:
                del items[k]
                forgotten.append(f"{hit} {k}")
    return sorted(set(forgotten), key=forgotten.index)
