"""The store's writer against an earlier revision of it and `.npy`, alternated in one run.

`writer_at(rev)` imports store/shard_writer.py as of git revision `rev` under another name;
while a baseline write runs, its `write_raw` and `ShardWriter` stand in for today's (the rest
of the store, the NaN/Inf guard, packing, the chunk CRC32C of `store/raw_shard.py` and the zarr
metadata are today's code, so only the writer differs; a change outside shard_writer.py is
compared by running `bench.cache_write` in two worktrees, alternated). The three writers
(`.npy`, baseline, current) take turns, the order rotated every round, each from the same
page-cache state (`bench.cache_write.alternating_writes`).

    python -m bench.cache_write_ab REV [ROUNDS] [VIEWS]
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

import bench.cache_write as cache_write
import store.cache_store as cache_store
from bench.cache_data import CacheBenchSpec, make_views


def writer_at(rev: str) -> ModuleType:
    """store/shard_writer.py as of git revision `rev`, imported as `baseline_shard_writer`."""
    text = subprocess.run(["git", "show", f"{rev}:store/shard_writer.py"], check=True,
                          capture_output=True, text=True).stdout
    folder = Path(tempfile.mkdtemp())
    path = folder / "baseline_shard_writer.py"
    path.write_text(text)
    try:
        spec = importlib.util.spec_from_file_location("baseline_shard_writer", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
    finally:
        shutil.rmtree(folder, ignore_errors=True)  # the module is loaded: its file is not needed
    return module


@contextmanager
def writing_with(module: ModuleType) -> Iterator[None]:
    """The store writes through `module`'s write_raw and ShardWriter inside the block."""
    places = [(cache_store, "write_raw"), (cache_write, "ShardWriter")]
    saved = [getattr(m, name) for m, name in places]
    for m, name in places:
        setattr(m, name, getattr(module, name))
    try:
        yield
    finally:
        for (m, name), value in zip(places, saved, strict=True):
            setattr(m, name, value)


def run_writer_ab(rev: str, rounds: int = 12, spec: CacheBenchSpec | None = None,
                  workdir: Path | None = None) -> dict[str, float]:
    """Figures of the writer at `rev` (`before_*`) and today's (`after_*`) against `.npy`,
    medians of `rounds` rotated rounds with the paired spread, and the load average before
    and after."""
    spec = spec or CacheBenchSpec()
    data = make_views(spec)
    baseline = writer_at(rev)

    def before(root: Path) -> float:
        with writing_with(baseline):
            return cache_write.write_zarr(root, data, spec)

    base = Path(tempfile.mkdtemp(prefix="m3gd-bench-writer-ab-", dir=workdir))
    load = os.getloadavg()[0]
    try:
        runs = cache_write.alternating_writes(base, {
            "npy": lambda root: cache_write.write_npy(root, data), "before": before,
            "after": lambda root: cache_write.write_zarr(root, data, spec)}, rounds)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    return {**runs.figures("before", "before"), **runs.figures("after", "after"),
            "load_avg_1min_before": load, "load_avg_1min_after": os.getloadavg()[0]}


if __name__ == "__main__":
    args = sys.argv[1:]
    figures = run_writer_ab(args[0], int(args[1]) if len(args) > 1 else 12,
                            CacheBenchSpec(views=int(args[2])) if len(args) > 2 else None)
    print(json.dumps({k: round(v, 3) for k, v in figures.items()}, indent=1))
