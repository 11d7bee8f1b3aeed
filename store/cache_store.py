"""Zarr v3 cache store: groups per recording and camera, arrays from `schemas.cache_layout`.

Arrays are created by zarr-python (so their metadata is what zarr-python reads). Raw
arrays (latents, images, packed h_cells) are written shard by shard in one pass by
`store.shard_writer` (byte-identical to tensorstore's files, faster); compressed
ones through tensorstore; all are read through tensorstore, which implements the same Zarr v3
sharding format several times faster than zarr-python here (docs/benchmarks.md). Writes are
shard-aligned: a writer owns whole shards and commits each shard as one file via temp file +
rename. A shard counts as complete only once its done-mark exists; marks are written after
all arrays of the shard, so a killed writer leaves no shard that looks complete.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec
from zarr.errors import ContainsArrayError, ContainsGroupError

from schemas.atomic_io import check_file, record_checksum, write_text_atomic
from schemas.cache_layout import (
    CACHE_DIRNAME,
    ArraySpec,
    GroupAttrs,
    check_root_attrs,
    group_name,
    region_for,
    root_attrs,
)
from schemas.errors import DataError, MissingInputError
from schemas.layout import DONE_DIRNAME, OutputLayout
from store.cache_io import write_views
from store.file_lock import flocked
from store.finite import all_finite
from store.shard_writer import ShardWriter, raw_block, run_or_submit, write_raw


def cache_path(output_dir: Path) -> Path:
    """Location of the cache store under an output directory."""
    return OutputLayout(output_dir).cache


def open_root(path: Path, create: bool = True) -> zarr.Group:
    """Open (or create) the cache root; refuse an unknown format version."""
    if not (path / "zarr.json").exists():
        if not create:
            raise MissingInputError(f"{path}: no m3gd cache here")
        try:  # one write of zarr.json with the attributes: never a root without a version
            return zarr.create_group(store=str(path), zarr_format=3, attributes=root_attrs())
        except ContainsGroupError:
            pass  # created meanwhile by an item running concurrently on another worker
    root = zarr.open_group(store=str(path), mode="r+" if create else "r", zarr_format=3)
    check_root_attrs(dict(root.attrs), str(path))
    return root


def camera_groups(root: zarr.Group, recording: str, cameras: list[str]) -> dict[str, Any]:
    """The cache groups of one recording that exist, by camera (cameras without one left out)."""
    return {c: root[group_name(recording, c)] for c in cameras if group_name(recording, c) in root}


def codecs_for(spec: ArraySpec) -> tuple[Any, Any]:
    """(filters, compressors) of the codec chain named by `spec.codec`; every chunk ends
    with its CRC32C (the `crc32c` codec, checked by every reader)."""
    if spec.codec == "zstd":
        return None, [ZstdCodec(level=1), Crc32cCodec()]
    return None, [Crc32cCodec()]


def ensure_array(group: zarr.Group, spec: ArraySpec, n_views: int, shard_views: int,
                 replace: bool = False) -> zarr.Array[Any]:
    """Create `spec` in `group` unless an array of the same shape and dtype exists.

    Items of one group run concurrently (encode shards, packets shard rows): when another
    worker creates the array first, its array is opened and checked like any existing one.
    An existing array of another shape or dtype is refused, or with `replace` (the writer
    stage's items, whose config changed: other channels, another dtype) replaced by an empty
    one, under the group's lock so that concurrent items replace it once.
    """
    if spec.name in group:
        arr = group[spec.name]
        assert isinstance(arr, zarr.Array)
    else:
        arr = _create(group, spec, n_views, shard_views)
    if not _fits(arr, spec, n_views) and replace:
        with group_lock(group):
            arr = group[spec.name]
            assert isinstance(arr, zarr.Array)
            if not _fits(arr, spec, n_views):  # not replaced meanwhile by another item
                del group[spec.name]
                arr = _create(group, spec, n_views, shard_views)
    if not _fits(arr, spec, n_views):
        raise DataError(
            f"{group.store_path}/{spec.name}: exists with shape {arr.shape} {arr.dtype}, "
            f"expected {spec.shape(n_views)} {spec.dtype}; remove it or use --force"
        )
    return arr


def _fits(arr: zarr.Array[Any], spec: ArraySpec, n_views: int) -> bool:
    """Whether `arr` has the shape and dtype of `spec` for `n_views` views."""
    return arr.shape == spec.shape(n_views) and str(arr.dtype) == spec.dtype


def _create(group: zarr.Group, spec: ArraySpec, n_views: int, shard_views: int) -> zarr.Array[Any]:
    """Create `spec` in `group` (or open it when another item created it meanwhile)."""
    filters, compressors = codecs_for(spec)
    try:
        return group.create_array(
            name=spec.name,
            shape=spec.shape(n_views),
            chunks=spec.chunks(shard_views),
            shards=spec.shards(shard_views),
            dtype=spec.dtype,
            filters=filters,
            compressors=compressors,
            fill_value=0,
            dimension_names=spec.dims,
        )
    except ContainsArrayError:
        arr = group[spec.name]
        assert isinstance(arr, zarr.Array)
        return arr


def drop_array(group: zarr.Group, name: str) -> None:
    """Remove array `name` of `group` if present (a writer whose config no longer makes it),
    under the group's lock."""
    if name in group:
        with group_lock(group):
            if name in group:
                del group[name]


@contextmanager
def group_lock(group: zarr.Group) -> Iterator[None]:
    """An exclusive lock on replacing the arrays of `group` (a lock file beside its
    done-marks; held by one process at a time, across the workers of one machine)."""
    path = _done_path(group, "arrays", 0).with_name(".arrays.lock")
    path.parent.mkdir(parents=True, exist_ok=True)
    with flocked(path):
        yield


def ensure_group(root: zarr.Group, attrs: GroupAttrs) -> zarr.Group:
    """Create or open the group of `attrs.recording/attrs.camera` and set its attributes."""
    name = group_name(attrs.recording, attrs.camera)
    group = root.require_group(name)
    old = dict(group.attrs)
    if old:
        known = GroupAttrs.from_attrs(old, f"{root.store_path}/{name}")
        if known.n_views != attrs.n_views:
            raise DataError(
                f"{root.store_path}/{name}: holds {known.n_views} views, run has {attrs.n_views}"
            )
    set_group_attrs(group, attrs.to_attrs())
    return group


def drop_damaged_meta(root: zarr.Group, name: str) -> bool:
    """Remove the `zarr.json` of group `name` when it no longer matches its checksum sidecar
    (damaged at rest; `m3gd verify` names it): the writer that recreates the group (ingest)
    calls this first, so the group is rebuilt as a clean run builds it. Whether it did."""
    meta = group_dir(root) / name / "zarr.json"
    if meta.exists() and check_file(meta) is not None:
        meta.unlink()
        return True
    return False


def set_group_attrs(group: zarr.Group, attrs: dict[str, Any]) -> None:
    """Update the attributes of `group` and record its `zarr.json`'s checksum sidecar, under
    the group's lock (items of one group may run at once)."""
    with group_lock(group):
        group.update_attributes(attrs)  # one write of zarr.json (attrs.update writes per key)
        record_checksum(group_dir(group) / "zarr.json")


def group_dir(group: zarr.Group) -> Path:
    """Directory of a local Zarr group."""
    return Path(str(group.store.root)) / group.path  # type: ignore[attr-defined]


def array_dir(arr: zarr.Array[Any]) -> Path:
    """Directory of a local Zarr array."""
    return Path(str(arr.store.root)) / arr.path  # type: ignore[attr-defined]


def _check_region(arr: zarr.Array[Any], start: int, shape: tuple[int, ...]) -> int:
    """Refuse a write of `shape` at view `start` that is not shard-aligned or does not fit;
    return the stop view."""
    shards = arr.shards
    stop = start + shape[0]
    if shards is not None:
        per = shards[0]
        if start % per or (stop % per and stop != arr.shape[0]):
            raise DataError(
                f"{arr.store_path}: write [{start}, {stop}) is not aligned to shards of {per}"
            )
    if shape[1:] != arr.shape[1:] or stop > arr.shape[0]:
        raise DataError(f"{arr.store_path}: data {shape} does not fit views {start}..{stop}"
                         f" of {arr.shape}")
    return stop


def _stored(arr: zarr.Array[Any], start: int, stop: int, data: np.ndarray) -> np.ndarray:
    """`data` cast to the array's dtype, refused (ValueError) when it holds NaN or Inf."""
    with np.errstate(over="ignore"):  # an overflowing cast gives Inf, refused just below
        stored = np.ascontiguousarray(data, dtype=arr.dtype)
    if stored.dtype.kind == "f" and not all_finite(stored):  # after the cast: f16 overflow too
        raise DataError(f"{arr.store_path}: refusing to write NaN or Inf to views {start}..{stop}")
    return stored


def write_region(arr: zarr.Array[Any], start: int, data: np.ndarray,
                 writer: ShardWriter | None = None) -> None:
    """Write views [start, start+len(data)) after checking the region is shard-aligned and
    the data finite (here, so errors raise in the caller); the file writes go to `writer`
    when given. Raw sharded arrays (latents, images) are written in one pass
    (`shard_writer.write_raw`), every other array through tensorstore.
    """
    stop = _check_region(arr, start, data.shape)
    stored = _stored(arr, start, stop, data)
    block = raw_block(arr)
    if block is not None:
        run_or_submit(writer, write_raw, arr, start, list(stored), block)
    else:
        run_or_submit(writer, write_views, array_dir(arr), start, stored)


def write_packed(cells: zarr.Array[Any], start: int, rows: list[np.ndarray],
                 writer: ShardWriter | None = None) -> None:
    """Write each view's packed rows (k_i, C_u) (schemas.packed_cells) into views
    [start, start + len(rows)) of `cells` (N, H*W, C_u); k_i must be the view's occupied
    cells (g[:, 0] == 1 of the same view), which is how readers find them.

    Only the chunks holding rows are stored (the rest read as zeros); each shard file is
    replaced whole, so no rows of an earlier run survive past the new counts.
    """
    stop = _check_region(cells, start, (len(rows), *cells.shape[1:]))
    for i, view_rows in enumerate(rows):
        if view_rows.ndim != 2 or len(view_rows) > cells.shape[1] or (
                view_rows.shape[1] != cells.shape[2]):
            raise DataError(f"{cells.store_path}: view {start + i}: rows {view_rows.shape} do "
                             f"not fit {cells.shape[1:]}")
    block = raw_block(cells)
    if block is None:
        raise DataError(f"{cells.store_path}: not a raw packed-rows array ({CACHE_DIRNAME} "
                         "format 3 stores h_cells uncompressed, each chunk with its CRC32C)")
    stored = [_stored(cells, start, stop, r) for r in rows]
    run_or_submit(writer, write_raw, cells, start, stored, block)


def _done_path(group: zarr.Group, stage: str, shard: int) -> Path:
    """File of the done-mark of one stage's shard: `<output>/cache_done/<group>/...`."""
    root = Path(str(group.store.root))  # type: ignore[attr-defined]
    return root.parent / DONE_DIRNAME / group.path / f"{stage}.{shard:06d}.json"


def mark_shard_done(group: zarr.Group, stage: str, shard: int, cache_key: str) -> None:
    """Atomically record that `stage` completed `shard` with `cache_key`."""
    write_text_atomic(_done_path(group, stage, shard),
                      json.dumps({"stage": stage, "shard": shard, "cache_key": cache_key}))


def shard_done(group: zarr.Group, stage: str, shard: int, cache_key: str) -> bool:
    """True when `stage` completed `shard` with the same cache key."""
    path = _done_path(group, stage, shard)
    if not path.exists():
        return False
    return bool(json.loads(path.read_text()).get("cache_key") == cache_key)


def stage_marked(group: zarr.Group, stage: str, n_shards: int) -> bool:
    """True when every one of `n_shards` shards carries a done-mark of `stage` (any key)."""
    return all(_done_path(group, stage, k).exists() for k in range(n_shards))


def shard_slice(shard: int, n_views: int, shard_views: int) -> slice:
    """The view slice of one shard."""
    start, stop = region_for(shard, n_views, shard_views)
    return slice(start, stop)
