"""Checking every stored chunk of a cache against its CRC32C, and marking the items that
wrote a corrupt chunk for the next run to redo.

Cache format 3 stores each chunk with its CRC32C (the `crc32c` codec; inside the shard for
sharded arrays). Readers check it on every read and refuse a corrupt chunk; this module
checks all of them at once (`m3gd verify`, `m3gd run --verify`), so a chunk damaged at rest
is found before training reads it. A corrupt chunk's item is forgotten: its stage's
done-mark for that shard is removed and the stage's manifest entries of that recording are
dropped, so the next run redoes them (the corrupt file is left in place until it is
rewritten: reading it keeps failing, it never reads as zeros).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import google_crc32c
import numpy as np

from schemas.cache_layout import H_CELLS, GridSpec, image_arrays, view_meta_arrays
from schemas.layout import DONE_DIRNAME
from schemas.manifest import RunManifest
from schemas.raw_shard import CRC_BYTES, MISSING
from schemas.shard_layout import ArrayMeta

_STAGE_OF = {**{s.name: "ingest" for s in image_arrays(GridSpec(14, 14))},
             **{s.name: "select" for s in view_meta_arrays()},
             "g": "packets", H_CELLS: "packets"}
"""The stage that writes each array (latents: encode, see `stage_of`)."""


def stage_of(array: str) -> str | None:
    """The stage that writes `array` (latents_l<k>: encode), None for an unknown array."""
    return "encode" if array.startswith("latents_l") else _STAGE_OF.get(array)


@dataclass(frozen=True)
class CorruptChunk:
    """A stored chunk whose bytes do not match their CRC32C (or cannot be located).

    group: '<recording>/<camera>'; shard: the file's number on the view axis (= the shard
    of the stages' done-marks); views: first and last view it holds (inclusive).
    """

    group: str
    array: str
    file: Path
    shard: int
    chunk: int
    views: tuple[int, int]
    detail: str

    def line(self) -> str:
        """One line naming the file, array, views and what is wrong."""
        return (f"{self.file}: {self.group}/{self.array} views {self.views[0]}..{self.views[1]} "
                f"(stored chunks from {self.chunk}): {self.detail}")  # fmt: skip


@dataclass
class VerifyReport:
    """What a verification found: chunks checked, corrupt ones, arrays it could not check."""

    checked: int = 0
    corrupt: list[CorruptChunk] = field(default_factory=list)
    unchecked: list[str] = field(default_factory=list)


def _crc_ok(data: bytes) -> bool:
    """Whether the last 4 bytes of `data` are the CRC32C of the rest."""
    if len(data) < CRC_BYTES:
        return False
    crc = int(google_crc32c.value(data[:-CRC_BYTES]))
    return crc == int.from_bytes(data[-CRC_BYTES:], "little")


def verify_cache(cache: Path) -> VerifyReport:
    """Check every stored chunk of every array of every `<recording>/<camera>` group."""
    report = VerifyReport()
    for meta_file in sorted(cache.glob("*/*/*/zarr.json")):
        folder = meta_file.parent
        meta = json.loads(meta_file.read_text())
        if meta.get("node_type") != "array":
            continue
        group = f"{folder.parent.parent.name}/{folder.parent.name}"
        parsed = ArrayMeta.parse(meta)
        if parsed is None or not parsed.crc:
            report.unchecked.append(f"{group}/{folder.name}")
            continue
        for checked, bad in verify_array(folder, group, parsed):
            report.checked += checked
            report.corrupt.extend(bad)
    return report


def verify_array(folder: Path, group: str, meta: ArrayMeta
                 ) -> Iterator[tuple[int, list[CorruptChunk]]]:
    """(chunks checked, corrupt chunks) per stored file of the array in `folder`."""
    n_files = -(-meta.shape[0] // meta.file_views)
    for shard in range(n_files):
        path = folder.joinpath("c", str(shard), *["0"] * (len(meta.shape) - 1))
        if path.is_file():
            yield _verify_file(path, group, folder.name, shard, meta)


def _verify_file(path: Path, group: str, array: str, shard: int,
                 meta: ArrayMeta) -> tuple[int, list[CorruptChunk]]:  # fmt: skip
    """Check one shard (or unsharded chunk) file."""
    first_view = shard * meta.file_views
    last_view = min(meta.shape[0], first_view + meta.file_views) - 1

    def bad(chunk: int, views: tuple[int, int], detail: str) -> CorruptChunk:
        return CorruptChunk(group, array, path, shard, chunk, views, detail)

    with path.open("rb") as f:
        fd, size = f.fileno(), os.fstat(f.fileno()).st_size
        if not meta.sharded:
            ok = _crc_ok(os.pread(fd, size, 0))
            return 1, [] if ok else [bad(0, (first_view, last_view), "CRC32C mismatch")]
        grid = [s // c for s, c in zip((meta.file_views, *meta.view_shape), meta.chunk,
                                       strict=True)]  # fmt: skip
        n = int(np.prod(grid))
        raw = os.pread(fd, 16 * n + 4, max(0, size - 16 * n - 4))
        if size < 16 * n + 4 or not _crc_ok(raw):
            return 1, [bad(-1, (first_view, last_view), "shard index CRC32C mismatch")]
        index = np.frombuffer(raw, "<u8", count=2 * n).reshape(n, 2)
        out: list[CorruptChunk] = []
        for k, (offset, nbytes) in enumerate(index.tolist()):
            if offset == int(MISSING):
                continue
            view = first_view + k // meta.chunks_per_view
            if offset + nbytes > size - 16 * n - 4 or not _crc_ok(os.pread(fd, nbytes, offset)):
                last = out[-1] if out else None
                if last is not None and last.views[1] in (view, view - 1):  # one line a run
                    out[-1] = bad(last.chunk, (last.views[0], view), last.detail)
                else:
                    out.append(bad(k, (view, view), "CRC32C mismatch"))
        return int((index[:, 0] != MISSING).sum()), out


def done_mark(cache: Path, group: str, stage: str, shard: int) -> Path:
    """The done-mark file of `stage`'s shard `shard` of `group` (pipeline.cache.store)."""
    return cache.parent / DONE_DIRNAME / group / f"{stage}.{shard:06d}.json"


def invalidate(cache: Path, manifest: RunManifest | None,
               corrupt: list[CorruptChunk]) -> list[str]:  # fmt: skip
    """Make the next run redo what wrote each corrupt chunk: remove its stage's done-mark of
    that shard and the stage's manifest entries of that recording. Returns what was
    forgotten, one '<stage> <item>' per entry."""
    from pipeline.run.keys import ItemKey

    forgotten: list[str] = []
    for c in corrupt:
        stage = stage_of(c.array)
        if stage is None:
            continue
        done_mark(cache, c.group, stage, c.shard).unlink(missing_ok=True)
        record = manifest.stages.get(stage) if manifest else None
        if record is None:
            continue
        recording, camera = c.group.split("/")
        for key in list(record.items):
            item = ItemKey.parse(key)
            if item.recording == recording and item.camera in (None, camera) and (
                    item.camera is None or item.shard == c.shard):
                del record.items[key]
                forgotten.append(f"{stage} {key}")
    return forgotten


def verify_output(out_dir: Path) -> tuple[VerifyReport, list[str]]:
    """Verify the cache of a local output folder (the caller holds its lock) and forget the
    items of every corrupt chunk in its manifest: (report, forgotten '<stage> <item>')."""
    from schemas.layout import OutputLayout
    from schemas.manifest import read_manifest, write_manifest

    cache = OutputLayout(out_dir).cache
    if not (cache / "zarr.json").exists():
        return VerifyReport(), []
    report = verify_cache(cache)
    if not report.corrupt:
        return report, []
    manifest = read_manifest(out_dir)
    forgotten = invalidate(cache, manifest, report.corrupt)
    if manifest is not None:
        write_manifest(manifest, out_dir)
    return report, forgotten
