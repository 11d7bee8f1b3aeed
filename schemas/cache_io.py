"""Reading and writing cache array data through tensorstore (same Zarr v3 format).

zarr-python creates the arrays and reads them too; tensorstore moves the bulk data
several times faster on this kind of machine (docs/benchmarks.md). Shared by the
pipeline (writers) and the model's dataset (readers).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np
import tensorstore as ts
from numpy.typing import NDArray

# No fsync per file (like np.save and zarr-python): atomicity comes from rename; a
# machine crash (not a process kill) may lose the last shards, which reruns redo.
_TS_CONTEXT = ts.Context({"file_io_sync": False})


@functools.lru_cache(maxsize=256)
def ts_handle(path: Path, write: bool = False) -> Any:
    """A tensorstore handle on the Zarr v3 array at `path` (cached per process)."""
    spec = {"driver": "zarr3", "kvstore": {"driver": "file", "path": str(path)},
            "recheck_cached_metadata": False}
    return ts.open(spec, read=True, write=write, context=_TS_CONTEXT).result()


def read_views(path: Path, frames: list[int]) -> NDArray[Any]:
    """Views `frames` (any order) of the array at `path`, stacked on axis 0."""
    return np.asarray(ts_handle(path)[frames].read().result())


def read_many(paths: list[Path], frames: list[int]) -> list[NDArray[Any]]:
    """Views `frames` of several arrays, all reads issued before any is awaited.

    tensorstore reads asynchronously, so the arrays of one clip load concurrently
    instead of one after another (one clip = latents, packets, cameras).
    """
    futures = [ts_handle(path)[frames].read() for path in paths]
    return [np.asarray(f.result()) for f in futures]


def write_views(path: Path, start: int, data: NDArray[Any]) -> None:
    """Write `data` into views [start, start + len(data)) of the array at `path`."""
    ts_handle(path, write=True)[start:start + len(data)].write(data).result()
