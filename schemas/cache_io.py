"""Reading cache array data, and writing compressed arrays, through tensorstore (same Zarr
v3 format).

zarr-python creates the arrays and reads them too; tensorstore moves the bulk data several
times faster on this kind of machine (docs/benchmarks.md); raw shards are written by
`pipeline.cache.shard_writer`. Shared by the pipeline (writers) and the model's dataset
(readers): `read_clip` is the one reader of a clip's arrays, packed h included.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import numpy as np
import tensorstore as ts
from numpy.typing import NDArray

from schemas.cache_layout import H_CELLS
from schemas.packed_cells import cell_counts, occupied_cells, unpack_rows

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


def read_clip(group: Path, names: list[str], frames: list[int]) -> dict[str, NDArray[Any]]:
    """Views `frames` of the arrays `names` of one cache group, read concurrently.

    The name "h" gives dense packet features (k, H, W, C_u), channels-last, unpacked from
    `h_cells` on the occupancy of g: g is awaited first, then only each view's occupied rows
    are read while the other arrays are still loading.
    """
    want_h = "h" in names
    plain = [n for n in names if n != "h"]
    plain += ["g"] if want_h and "g" not in plain else []
    futures = {n: ts_handle(group / n)[frames].read() for n in plain}
    out: dict[str, NDArray[Any]] = {}
    if want_h:
        out["g"] = np.asarray(futures.pop("g").result())
        occupied = occupied_cells(out["g"])
        rows = start_row_reads(group / H_CELLS, frames, cell_counts(occupied))
        out.update((n, np.asarray(f.result())) for n, f in futures.items())
        out["h"] = unpack_rows([np.asarray(r.result()) for r in rows], occupied)
        if "g" not in names:
            del out["g"]
        return out
    return {n: np.asarray(f.result()) for n, f in futures.items()}
