"""Checking every stored chunk of a cache against its CRC32C, and marking the items that
wrote a corrupt chunk for the next run to redo.

Cache format 3 stores each chunk with its CRC32C (the `crc32c` codec; inside the shard for
sharded arrays). Readers check it on every read and refuse a corrupt chunk; this module
checks all of them at once (`m3gd verify`, `m3gd run --verify`), so a chunk damaged at rest
is found before training reads it. It also finds arrays that a done stage wrote but that are
gone, and a latent normalization that no longer matches the valid views of its groups.

Every table and metadata file the stages write outside the chunks (index tables, statistics
parts and tables, the clip index, the cache groups' `zarr.json`, the run manifest) carries a
checksum sidecar (`schemas.atomic_io.checksum_path`); `verify_files` checks each against its
file and names a damaged, cut or missing one with the stage item that writes it, which is
forgotten with its dependants in the same way (`forget_files`).

A damaged array is redone by the stage that writes it (declared once, in
`schemas.cache_layout`) and by every stage that depends on it (the stage graph): their
done-marks and manifest items covering what the writer redoes are forgotten, so the next run
rewrites exactly those arrays and everything derived from them (`invalidate`). Nothing is
deleted here: a corrupt file is left in place until it is rewritten (reading it keeps
failing, it never reads as zeros).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import google_crc32c
import numpy as np

from pipeline.run.checksums import (
    NORM_ATTR,
    DamagedFile,
    Dependants,
    Scope,
    forget_files,
    metadata_problem,
    unmark,
    verify_files,
)
from pipeline.run.keys import ItemKey
from schemas.cache_layout import (
    GroupAttrs,
    LatentNorm,
    arrays_written_by,
    layout_arrays,
    writer_stage,
)
from schemas.layout import DONE_DIRNAME, OutputLayout
from schemas.manifest import (
    ManifestDamaged,
    RunManifest,
    read_manifest,
    set_aside,
    write_manifest,
)
from schemas.modes import MODE_ARRAYS
from schemas.stages import STAGE_TABLE, Granularity, StageSpec, writer_of_root_attr
from store.raw_shard import CRC_BYTES, MISSING
from store.shard_layout import ArrayMeta

SHARD_MARKED = tuple(s.name for s in STAGE_TABLE if s.items == Granularity.SHARD)
"""Stages whose done-marks cover one shard of one camera: a redo of theirs covers that shard
(the others' items cover a whole recording)."""
NORM_ITEM = ItemKey.cross(NORM_ATTR).format()
"""The item of the latent normalization (a cross item of the stage that writes it,
pipeline.stages.stats)."""


def _norm_stage() -> StageSpec:
    """The stage that writes the latent normalization (the stage table's row)."""
    spec = writer_of_root_attr(NORM_ATTR)
    assert spec is not None, f"no stage of the table writes {NORM_ATTR}"
    return spec


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


@dataclass(frozen=True)
class MissingArray:
    """An array its writer's done-marks (or the run manifest) say was written, but absent."""

    group: str
    array: str
    stage: str

    def line(self) -> str:
        """One line naming the group, the array and the stage that wrote it."""
        return f"{self.group}/{self.array}: missing, though {self.stage} is marked done"


@dataclass
class VerifyReport:
    """What a verification found: chunks checked, corrupt ones, arrays it could not check,
    arrays that are gone, and a latent normalization that no longer describes the cache."""

    checked: int = 0
    corrupt: list[CorruptChunk] = field(default_factory=list)
    unchecked: list[str] = field(default_factory=list)
    missing: list[MissingArray] = field(default_factory=list)
    stale_norm: str | None = None
    files_checked: int = 0
    """Tables and metadata files checked against their checksum sidecars."""
    files: list[DamagedFile] = field(default_factory=list)
    manifest: str | None = None
    """Why the run manifest was set aside (it did not match its checksum or parse)."""

    @property
    def damaged(self) -> bool:
        """Whether anything needs a redo."""
        return bool(self.corrupt or self.missing or self.stale_norm or self.files
                    or self.manifest)


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
        if metadata_problem(meta_file) is not None:
            continue  # named by `verify_files` with its writer; its array is rewritten
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
    """The done-mark file of `stage`'s shard `shard` of `group` (store.cache_store)."""
    return cache.parent / DONE_DIRNAME / group / f"{stage}.{shard:06d}.json"


def scope_of(stage: str, group: str, shard: int | None) -> Scope:
    """What a redo of `stage` for a damaged `shard` of `group` covers (shard None: the whole
    array): the shard for the shard-marked stages, else the whole recording."""
    recording, camera = group.split("/")
    if stage in SHARD_MARKED:
        return Scope(recording, camera, shard)
    return Scope(recording)


Damage = tuple[str, str, int | None]
"""(group, array, shard or None for the whole array) of a corrupt chunk or missing array."""


def drop_marks_past(cache: Path, group: str, n_shards: int) -> list[Path]:
    """Remove the done-marks of `group`'s shards from `n_shards` on (left by an earlier layout
    with more shards); returns them."""
    gone = []
    for mark in (cache.parent / DONE_DIRNAME / group).glob("*.*.json"):
        shard = mark.name.split(".")[-2]
        if shard.isdigit() and int(shard) >= n_shards:
            mark.unlink(missing_ok=True)
            gone.append(mark)
    return gone


def done_key(cache: Path, group: str, stage: str, shard: int) -> str | None:
    """The cache key `stage`'s done-mark of `shard` of `group` carries, None without one."""
    path = done_mark(cache, group, stage, shard)
    try:
        key = json.loads(path.read_text()).get("cache_key")
    except (OSError, ValueError):
        return None
    return key if isinstance(key, str) else None


def invalidate(cache: Path, manifest: RunManifest | None, damage: Sequence[Damage],
               dependants: Dependants) -> list[str]:
    """Make the next run redo what wrote each damaged array and everything that read it.

    damage: (group, array, shard or None for the whole array). The array's writer stage
    (`schemas.cache_layout.writer_stage`) and each of its dependants forget the scope the
    writer redoes (`scope_of`): their done-marks there and their manifest items that overlap
    it (their cross-recording items too). Nothing is deleted: the arrays are rewritten by the
    rerun. Returns what was forgotten, one '<stage> <item>' per manifest entry.
    """
    forgotten: list[str] = []
    for group, array, shard in damage:
        stage = writer_stage(array)
        if stage is None:
            continue
        scope = scope_of(stage, group, shard)
        for hit in dependants(stage):
            unmark(cache, hit, scope)
            items = manifest.stages[hit].items if manifest and hit in manifest.stages else {}
            for key in [k for k in items if scope.covers(k)]:
                del items[key]
                forgotten.append(f"{hit} {key}")
    return forgotten


def missing_arrays(cache: Path, manifest: RunManifest | None) -> list[MissingArray]:
    """Arrays a stage is marked done for (done-marks of the shard-marked stages, the manifest
    for the others) that are absent from their group."""
    out: list[MissingArray] = []
    for meta in sorted(cache.glob("*/*/zarr.json")):
        folder = meta.parent
        group = f"{folder.parent.name}/{folder.name}"
        try:
            attrs = GroupAttrs.from_attrs(json.loads(meta.read_text()).get("attributes", {}),
                                          group)
        except (ValueError, TypeError):
            continue
        marks = cache.parent / DONE_DIRNAME / group
        for stage in dict.fromkeys(s.writer_stage for s in layout_arrays() if s.writer_stage):
            if stage in SHARD_MARKED:
                done = attrs.n_views > 0 and any(marks.glob(f"{stage}.*.json"))
            else:
                record = manifest.stages.get(stage) if manifest else None
                done = record is not None and folder.parent.name in record.items
            with_h = "h" in MODE_ARRAYS.get(attrs.packet_mode or "", ())
            out += [MissingArray(group, a, stage) for a in arrays_written_by(stage, with_h)
                    if done and not (folder / a / "zarr.json").exists()]
    return out


def stale_norm(cache: Path) -> str | None:
    """Why the cache's recorded latent normalization no longer describes its groups (their
    valid views), or None (also when there is none: the stats stage computes it)."""
    root = cache / "zarr.json"
    if metadata_problem(root) is not None:
        return None  # named by `verify_files`; the stats stage writes it anew
    norm = LatentNorm.from_attrs(json.loads(root.read_text()).get("attributes", {})
                                 .get(NORM_ATTR))  # fmt: skip
    if norm is None:
        return None
    return norm.stale_against({g: valid_views(cache / g) for g in norm.groups})


def valid_views(group: Path) -> int | None:
    """Valid views of a cache group (its `valid` array), None when it cannot be read."""
    from store.cache_io import read_views

    try:
        n = int(json.loads((group / "valid" / "zarr.json").read_text())["shape"][0])
        return int(np.count_nonzero(read_views(group / "valid", list(range(n)))))
    except (OSError, ValueError, KeyError):
        return None


def drop_done_marks(cache: Path) -> list[Path]:
    """Remove every done-mark of the cache's groups (with the run manifest set aside, nothing
    says which stage items they belong to: every stage is redone); returns them."""
    marks = [m for m in (cache.parent / DONE_DIRNAME).glob("*/*/*.json")
             if m.name.count(".") == 2 and m.name.split(".")[1].isdigit()]
    for mark in marks:
        mark.unlink(missing_ok=True)
    return marks


def verify_output(out_dir: Path, dependants: Dependants) -> tuple[VerifyReport, list[str]]:
    """Verify a local output folder (the caller holds its lock): the cache's chunks, and every
    table and metadata file against its checksum sidecar; forget, in its manifest and
    done-marks, what a rerun must redo: the writers of every corrupt chunk, missing array and
    damaged file and their dependants, and a stale latent normalization. A manifest that
    does not match its checksum or parse is set aside (`schemas.manifest.set_aside`): the
    next run rebuilds it. Returns (report, forgotten '<stage> <item>')."""
    cache = OutputLayout(out_dir).cache
    has_cache = (cache / "zarr.json").exists()
    report = verify_cache(cache) if has_cache else VerifyReport()
    try:
        manifest = read_manifest(out_dir)
    except ManifestDamaged as err:
        report.manifest = f"{err.detail}; set aside as {set_aside(out_dir)}: the next run " \
                          "rebuilds it, redoing every stage"
        drop_done_marks(cache)
        manifest = None
    report.files_checked, report.files = verify_files(out_dir)
    if has_cache:
        report.missing = missing_arrays(cache, manifest)
        report.stale_norm = stale_norm(cache)
    if not report.damaged:
        return report, []
    forgotten = forget_files(cache, manifest, report.files, dependants)
    damage = [*((c.group, c.array, c.shard) for c in report.corrupt),
              *((m.group, m.array, None) for m in report.missing)]
    forgotten += [f for f in invalidate(cache, manifest, damage, dependants)
                  if f not in forgotten]
    norm_stage = _norm_stage().name
    record = manifest.stages.get(norm_stage) if manifest else None
    if report.stale_norm and record is not None and NORM_ITEM in record.items:
        del record.items[NORM_ITEM]
        forgotten.append(f"{norm_stage} {NORM_ITEM}")
    if manifest is not None:
        write_manifest(manifest, out_dir)
    return report, forgotten
