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

import json
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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
from schemas.stages import (
    STAGE_TABLE,
    Granularity,
    writer_of_array,
    writer_of_root_attr,
    writer_of_table,
)

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
    camera: str | None = None
    """The camera a redo of a recording's item is narrowed to (an array of one camera
    written by a stage whose items are shards: every shard of that camera)."""

    def line(self) -> str:
        """One line naming the file, what is wrong and what rewrites it."""
        item = f"{self.item} (camera {self.camera})" if self.camera else self.item
        by = (f"written by {self.stage} {item}, redone by the next run" if self.stage
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


ZARR_META = "zarr.json"
NORM_ATTR = "latent_norm"
"""The cache root's attribute written by a stage (the rest of the root is the format's)."""


EMPTY_GROUP = {"attributes": {}, "zarr_format": 3, "node_type": "group"}
"""The metadata of a recording's group in the cache (its cameras' groups hold the rest)."""


def cache_metadata(out_dir: Path) -> list[Path]:
    """The `zarr.json` of every node of the output's cache: the root, the recording and
    camera groups and the arrays of each camera group: every such folder that holds a file
    (an empty folder a deleted array left is no node)."""
    cache = out_dir / CACHE_DIRNAME
    if not cache.is_dir():
        return []
    nodes = [cache, *(p for depth in range(1, 4)
                      for p in cache.glob("/".join(["*"] * depth)) if p.is_dir())]
    return sorted(p / ZARR_META for p in nodes
                  if (p / ZARR_META).exists() or any(f.is_file() for f in p.rglob("*")))


def metadata_problem(path: Path) -> str | None:
    """Why the Zarr v3 metadata file `path` cannot be what the cache wrote (it is missing,
    does not parse as JSON, is not a group or array node, an array without shape, data type, chunk
    grid or codecs), or None."""
    try:
        raw = json.loads(path.read_bytes())
    except FileNotFoundError:
        return "missing"
    except (OSError, ValueError) as err:
        return f"does not parse as Zarr metadata ({type(err).__name__}: {err})"
    if not isinstance(raw, dict) or raw.get("zarr_format") != 3 \
            or raw.get("node_type") not in ("group", "array"):
        return "not the metadata of a Zarr v3 group or array"
    if raw["node_type"] == "array" and not (
            isinstance(raw.get("shape"), list) and isinstance(raw.get("data_type"), str)
            and isinstance(raw.get("chunk_grid"), dict) and isinstance(raw.get("codecs"), list)):
        return "Zarr array metadata without its shape, data type, chunk grid or codecs"
    depth = len(path.parts) - path.parts.index(CACHE_DIRNAME) - 1 \
        if CACHE_DIRNAME in path.parts else 0
    if depth == 2 and {k: v for k, v in raw.items() if v is not None} != EMPTY_GROUP:
        return "a recording group's Zarr metadata with other keys or attributes than none"
    if raw["node_type"] == "array" and depth == 4:
        return array_meta_problem(path, raw)
    return None


def array_meta_problem(path: Path, raw: dict[str, Any]) -> str | None:
    """Why the parsed metadata `raw` of the cache array at `path` (`<group>/<array>/
    zarr.json`) is not what the layout declares for it in its group (`expected_array_meta`:
    shape, dtype, chunks, codecs, dimension names, fill value; every key), or None; None
    too when the group's attributes cannot be read (the group is named on its own)."""
    from schemas.cache_layout import GroupAttrs

    try:
        group = json.loads((path.parent.parent / ZARR_META).read_bytes())
        attrs = GroupAttrs.from_attrs(group.get("attributes", {}), str(path.parent.parent))
    except (OSError, ValueError, TypeError, AttributeError):
        return None
    want = expected_array_meta(path.parent.name, attrs, raw)
    if want is None:
        return None  # an array the layout does not declare: not the cache's to judge
    if raw != want:
        keys = sorted(k for k in {*raw, *want} if raw.get(k) != want.get(k))
        return f"Zarr array metadata differs from the layout's in {', '.join(keys)}"
    return None


def expected_array_meta(name: str, attrs: Any, raw: dict[str, Any]) -> dict[str, Any] | None:
    """The `zarr.json` the cache writes for array `name` of a group with attributes `attrs`
    (`schemas.cache_layout.GroupAttrs`); the latents' dtype and the channels of the latents
    and of h_cells from the encoders the group records (from `raw` before they are)."""
    from schemas.cache_layout import (
        LATENT_PREFIX,
        GridSpec,
        image_arrays,
        latent_array,
        packet_arrays,
        view_meta_arrays,
    )

    grid = GridSpec(attrs.image_h, attrs.image_w, attrs.patch)
    shape = raw.get("shape") or [0, 0, 0]
    level = name[len(LATENT_PREFIX):]
    if name.startswith(LATENT_PREFIX) and level.isdigit():
        enc = attrs.image_encoder
        channels = enc.channels if enc is not None else int(shape[1])
        dtype = str(raw.get("data_type"))
        specs = [latent_array(grid, channels, dtype if dtype in ("float16", "float32")
                              else "float16", int(level))]
    else:
        enc = attrs.point_encoder
        point = enc.channels if enc is not None else int(shape[-1]) if len(shape) == 3 else 1
        specs = [*image_arrays(grid), *view_meta_arrays(), *packet_arrays(grid, point, True)]
    spec = next((s for s in specs if s.name == name), None)
    if spec is None:
        return None
    one_byte = spec.dtype in ("uint8", "int8", "bool")
    inner: list[dict[str, Any]] = [
        {"name": "bytes"} if one_byte else
        {"name": "bytes", "configuration": {"endian": "little"}},
        *([{"name": "zstd", "configuration": {"level": 1, "checksum": False}}]
          if spec.codec == "zstd" else []), {"name": "crc32c"}]
    sv = attrs.shard_views
    outer = spec.shards(sv) or spec.chunks(sv)
    codecs = [{"name": "sharding_indexed", "configuration": {
        "chunk_shape": list(spec.chunks(sv)), "codecs": inner,
        "index_codecs": [{"name": "bytes", "configuration": {"endian": "little"}},
                         {"name": "crc32c"}], "index_location": "end"}}] if spec.sharded \
        else inner
    fill: Any = False if spec.dtype == "bool" else 0.0 if spec.dtype.startswith("float") else 0
    return {"shape": list(spec.shape(attrs.n_views)), "data_type": spec.dtype,
            "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": list(outer)}},
            "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
            "fill_value": fill, "codecs": codecs, "attributes": {},
            "dimension_names": list(spec.dims), "zarr_format": 3, "node_type": "array",
            "storage_transformers": []}


def metadata_writer(rel: tuple[str, ...]) -> tuple[str, str, str | None] | None:
    """(stage, formatted item key) that writes the cache metadata of the node at `rel` (its
    path in the cache, () for the root): the root by the stage that writes its `latent_norm`
    (its cross item), a recording or camera group by GROUP_WRITER's item of the recording,
    an array by its writer (the stage table), for the whole camera or recording its items
    cover (the camera for a stage whose items are shards, else None)."""
    if not rel:
        spec = writer_of_root_attr(NORM_ATTR)
        return None if spec is None else (spec.name, ItemKey.cross(NORM_ATTR).format(), None)
    if len(rel) in (1, 2):
        return GROUP_WRITER, ItemKey(rel[0]).format(), None
    spec = writer_of_array(rel[2])
    if spec is None:
        return None
    return spec.name, ItemKey(rel[0]).format(), \
        rel[1] if spec.items == Granularity.SHARD else None


def damaged_metadata(out_dir: Path, found: Sequence[Path]) -> list[DamagedFile]:
    """The cache's `zarr.json` files (those not in `found` already) that cannot be the
    metadata the cache wrote (`metadata_problem`), each with the stage item that writes it."""
    cache = out_dir / CACHE_DIRNAME
    out = []
    for path in cache_metadata(out_dir):
        why = None if path in found else metadata_problem(path)
        if why is not None:
            owner = metadata_writer(path.parent.relative_to(cache).parts)
            out.append(DamagedFile(path, why, *(owner or (None, None, None))))
    return out


def rebuild_metadata(cache: Path, damaged: Sequence[DamagedFile]) -> None:
    """Make the damaged cache metadata files rewritable by the items that are redone: the
    root is written anew with the format's attributes (the stage that writes its
    `latent_norm` is redone), a recording group's metadata anew (it holds nothing else); a
    camera group's metadata that does not parse and has no sidecar is removed (one with a
    sidecar is removed by GROUP_WRITER, `drop_damaged_meta`, which recreates the camera), an
    array with damaged metadata is removed whole (its writer rewrites every
    view). The root's first, so that the groups below can be opened."""
    from store.cache_store import open_root  # zarr: slow to import

    for file in sorted(damaged, key=lambda f: len(f.path.parts)):
        if file.path.name != ZARR_META or cache not in file.path.parents:
            continue
        depth = len(file.path.relative_to(cache).parts)
        if depth == 1:
            file.path.unlink(missing_ok=True)
            checksum_path(file.path).unlink(missing_ok=True)
            open_root(cache)
        elif depth == 2:
            file.path.unlink(missing_ok=True)
            open_root(cache).require_group(file.path.parent.name)
        elif depth == 3 and not checksum_path(file.path).exists() \
                and metadata_problem(file.path) is not None:
            file.path.unlink(missing_ok=True)
        elif depth == 4:
            shutil.rmtree(file.path.parent, ignore_errors=True)


def writer_of(out_dir: Path, path: Path) -> tuple[str, str] | None:
    """(stage, formatted item key) that writes `path`: its sidecar's record; a cache group's
    `zarr.json` by the GROUP_WRITER item of its recording; an index table, when its sidecar
    cannot be read, by the stage the stage table says writes it (by its name)."""
    rel = path.relative_to(out_dir).parts
    if rel[0] == CACHE_DIRNAME and path.name == ZARR_META:
        owner = metadata_writer(rel[1:-1])
        return None if owner is None else owner[:2]
    found = read_sidecar(checksum_path(path))
    if found is not None and found.stage and found.item:
        return found.stage, found.item
    spec = writer_of_table(Path(rel[-1]).stem) if rel[0] == INDEX_DIRNAME and len(rel) == 3 \
        else None
    return None if spec is None else (spec.name, rel[1])


def verify_files(out_dir: Path) -> tuple[int, list[DamagedFile]]:
    """(files checked, damaged ones): each guarded file against its sidecar, then every
    `zarr.json` of the cache that does not parse as the metadata the cache wrote (arrays'
    and the recording groups' carry no sidecar: Zarr writes them)."""
    damaged = []
    files = guarded_files(out_dir)
    for path in files:
        why = check_file(path)
        if why is not None:
            owner = writer_of(out_dir, path)
            damaged.append(DamagedFile(path, why, *(owner or (None, None))))
    meta = cache_metadata(out_dir)
    damaged += damaged_metadata(out_dir, [f.path for f in damaged])
    return len(set(files) | set(meta)), damaged


def forget_files(cache: Path, manifest: RunManifest | None, damaged: Sequence[DamagedFile],
                 dependants: Dependants) -> list[str]:
    """Make the next run redo the stage item that writes each damaged file and, within what
    it redoes, every stage that depends on it (their done-marks and manifest items, as
    `invalidate`), after making damaged cache metadata rewritable (`rebuild_metadata`);
    returns what was forgotten, one '<stage> <item>' per manifest entry."""
    rebuild_metadata(cache, damaged)
    forgotten: list[str] = []
    for file in damaged:
        if file.stage is None or file.item is None:
            continue
        key = ItemKey.parse(file.item)
        scope = None if key.is_cross else Scope(key.require_recording(),
                                                key.camera or file.camera, key.shard)
        for hit in dependants(file.stage):
            if scope is not None:
                unmark(cache, hit, scope)
            items = manifest.stages[hit].items if manifest and hit in manifest.stages else {}
            for k in [k for k in items if (scope.covers(k) if scope is not None
                                           else hit != file.stage or k == file.item)]:
                del items[k]
                forgotten.append(f"{hit} {k}")
    return sorted(set(forgotten), key=forgotten.index)
