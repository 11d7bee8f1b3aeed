"""What the shard reader's filesystem fallbacks cost: warm clip reads (the loader's
`read_clip` through one `ShardReader`) of one cache, on the local disk and on a tmpfs, by

- `probe`: the reader as shipped (RWF_NOWAIT where the filesystem takes it, else learned off
  on the first refusal);
- `no_nowait`: the flag known off from the start (what tmpfs and network mounts get);
- `pread`: preadv known refused too (one pread per buffer: platforms without preadv);
- `baseline` (with `--baseline REV`): the reader of git revision REV, before the fallbacks
  (local disk only: on tmpfs it failed with EOPNOTSUPP).

Figures are seconds per clip, the readers taking turns block by block (bench.support.
cache_floor.interleaved), and ratios to `probe` in the same run. Run:
`python -m bench.reader_fs_bench [--baseline REV] [--views N]`.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from bench.cache_bench import (
    GROUP,
    STORE_NAMES,
    clip_starts,
    same_clip,
)
from bench.cache_data import CacheBenchSpec, make_views
from bench.cache_write import write_zarr
from bench.support.cache_floor import interleaved
from store.cache_io import read_clip
from store.pread_io import FsReads
from store.shard_reader import ShardReader


def _reader_at(rev: str) -> ModuleType:
    """The shard reader as of git revision `rev` (store/shard_reader.py; schemas/ before the
    store package), imported under another name."""
    for where in ("store/shard_reader.py", "schemas/shard_reader.py"):
        got = subprocess.run(["git", "show", f"{rev}:{where}"], capture_output=True, text=True)
        if got.returncode == 0:
            break
    got.check_returncode()
    text = got.stdout
    path = Path(tempfile.mkdtemp()) / "baseline_shard_reader.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("baseline_shard_reader", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _forced(fs: FsReads) -> ShardReader:
    """A reader that takes every filesystem to support only what `fs` says."""
    reader = ShardReader()

    class _Fixed(dict[int, FsReads]):
        def setdefault(self, key: int, default: Any = None) -> FsReads:
            return super().setdefault(key, FsReads(fs.nowait, fs.vectored))

    reader._fs = _Fixed()
    return reader


def bench_dir(base: Path, spec: CacheBenchSpec, baseline: ModuleType | None,
              repeats: int) -> dict[str, float]:
    """Seconds per warm clip of each reader over a cache written under `base`."""
    root = base / "cache.zarr"
    write_zarr(root, make_views(spec), spec)
    group = root.joinpath(*GROUP)
    readers: dict[str, Any] = {
        "probe": ShardReader(), "no_nowait": _forced(FsReads(False, True)),
        "pread": _forced(FsReads(False, False))}
    if baseline is not None:
        readers["baseline"] = baseline.ShardReader()
    reads: dict[str, Callable[[list[int]], dict[str, np.ndarray]]] = {
        name: functools.partial(read_clip, group, STORE_NAMES, reader=r)
        for name, r in readers.items()}
    clips = clip_starts(spec)
    for frames in clips:  # warms the page cache and every reader's handles; same bytes
        same_clip(frames, [read(frames) for read in reads.values()])
    seconds = interleaved(reads, clips, repeats)
    return {name: s / len(clips) for name, s in seconds.items()}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="git revision of the reader to compare with")
    parser.add_argument("--views", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--tmpfs", default="/dev/shm", help="a directory on a tmpfs")
    args = parser.parse_args(argv)
    spec = CacheBenchSpec(views=args.views, channels=768, point_channels=612, clips=200)
    baseline = _reader_at(args.baseline) if args.baseline else None
    out: dict[str, Any] = {"views": spec.views, "clips": spec.clips}
    for label, where in (("local", None), ("tmpfs", args.tmpfs)):
        base = Path(tempfile.mkdtemp(prefix="m3gd-fsbench-", dir=where))
        try:
            per_clip = bench_dir(base, spec, baseline if where is None else None,
                                 args.repeats)
        finally:
            shutil.rmtree(base, ignore_errors=True)
        out[label] = {"ms_per_clip": {k: round(v * 1e3, 4) for k, v in per_clip.items()},
                      "ratio_to_probe": {k: round(v / per_clip["probe"], 3)
                                         for k, v in per_clip.items()}}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
