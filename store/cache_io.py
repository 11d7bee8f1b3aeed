"""Reading cache array data, and writing compressed arrays, through tensorstore (same Zarr
v3 format).

zarr-python creates the arrays and reads them too; tensorstore moves the bulk data several
times faster on this kind of machine (docs/benchmarks.md); raw shards are written by
`store.shard_writer`. Shared by the pipeline (writers) and the model's dataset
(readers): `read_clip` is the one reader of a clip's arrays, packed h included; it reads
through `store.shard_reader` (cached handles and shard indexes, one pread per view).
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import tensorstore as ts
from numpy.typing import NDArray

from schemas.cache_layout import H_CELLS
from schemas.packed_cells import cell_counts, occupied_cells, unpack_packed
from store.shard_reader import ShardReader

# No fsync per file (like np.save and zarr-python): atomicity comes from rename; a
# machine crash (not a process kill) may lose the last shards, which reruns redo.
_TS_CONTEXT = ts.Context({"file_io_sync": False})


def node_attrs(path: Path) -> dict[str, Any]:
    """Attributes of the Zarr v3 node (group or array) whose directory is `path`."""
    attrs = json.loads((path / "zarr.json").read_text()).get("attributes", {})
    return attrs if isinstance(attrs, dict) else {}


@functools.lru_cache(maxsize=256)
def ts_handle(path: Path, write: bool = False) -> Any:
    """A tensorstore handle on the Zarr v3 array at `path` (cached per process)."""
    spec = {"driver": "zarr3", "kvstore": {"driver": "file", "path": str(path)},
            "recheck_cached_metadata": False}
    return ts.open(spec, read=True, write=write, context=_TS_CONTEXT).result()


def read_views(path: Path, frames: list[int]) -> NDArray[Any]:
    """Views `frames` (any order) of the array at `path`, stacked on axis 0."""
    return np.asarray(ts_handle(path)[frames].read().result())


def write_views(path: Path, start: int, data: NDArray[Any]) -> None:
    """Write `data` into views [start, start + len(data)) of the array at `path`."""
    ts_handle(path, write=True)[start:start + len(data)].write(data).result()


def start_row_reads(path: Path, frames: list[int], counts: NDArray[Any]) -> list[Any]:
    """Start reading rows [0, counts[i]) of view frames[i] of a packed-rows array (futures)."""
    handle = ts_handle(path)
    return [handle[f, :int(c)].read() for f, c in zip(frames, counts, strict=True)]


_READERS: dict[int, ShardReader] = {}


def default_reader() -> ShardReader:
    """This process's shared `ShardReader` (one per pid: a forked child gets its own)."""
    return _READERS.setdefault(os.getpid(), ShardReader())


def _views(reader: ShardReader, path: Path, frames: list[int]) -> NDArray[Any]:
    """Views `frames` of one array: the pread reader, or tensorstore for layouts it does not
    read (none that m3gd writes)."""
    if reader.meta(path) is None:
        return read_views(path, frames)
    return reader.read_views(path, frames)


def read_clip(group: Path, names: list[str], frames: list[int],
              reader: ShardReader | None = None) -> dict[str, NDArray[Any]]:
    """Views `frames` of the arrays `names` of one cache group.

    Packet features come in two forms, both placed by the validity channel of g (read too):
    - "h_rows": packed rows (sum_i k_i, C_u), view after view, each view's rows in row-major
      order of its occupied cells g[i, 0] > 0.5 (schemas.packed_cells): what is stored,
      moved with one pread per view and no densifying (the model scatters them);
    - "h": dense channels-last (k, H, W, C_u), zero on unoccupied cells.
    Reads go through `reader` (default: this process's), which keeps shard files open and
    their indexes parsed across calls (store.shard_reader).
    """
    reader = reader or default_reader()
    packed = [n for n in names if n in ("h", "h_rows")]
    plain = [n for n in dict.fromkeys([*(["g"] if packed else []), *names]) if n not in packed]
    stored = [*plain, *([H_CELLS] if packed else [])]

    def prefetch() -> None:  # on the first read that misses the page cache
        for name in stored:
            reader.prefetch(group / name, frames)

    with reader.on_first_miss(prefetch):
        out = {n: _views(reader, group / n, frames) for n in plain}
        if packed:
            occupied = occupied_cells(out["g"])
            rows = reader.read_rows(group / H_CELLS, frames, cell_counts(occupied))
    if packed:
        if "h_rows" in names:
            out["h_rows"] = rows
        if "h" in names:
            out["h"] = unpack_packed(rows, occupied)
        if "g" not in names:
            del out["g"]
    return out
