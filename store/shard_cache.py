"""Read-through local cache of a cache's objects on S3: whole shard objects, bounded in bytes.

Readers of an output on `s3://…` (the trainer's `ClipStream`) read from a local mirror
directory with the same layout as the store, so the local readers (tensorstore, the shard
reader) are used unchanged. An object is fetched whole with one GET the first time a clip
needs it (as MosaicML Streaming does with its shard files) and kept while the mirror holds
less than `limit_bytes` of shard objects; beyond that the least recently used shard objects
are removed (never those of the clip being read, so the mirror may exceed the limit by one
clip's objects; eviction walks the mirror, a cost paid only after a fetch). Metadata
(zarr.json, Parquet tables) is small, fetched once and never evicted.

Why whole shards and not ranged reads: a clip reads V views of ~6 arrays; ranged reads cost
one GET per shard index plus one per view and array (tens per clip), whole shards one GET
per array and shard unit, and the stream deals whole shard units to workers so the rest of
a fetched shard is read by the same worker next (`m3gd bench storage`, docs/benchmarks.md).

Concurrency: several processes (DataLoader workers, ranks on one host) may share one mirror.
Objects appear by rename of a complete temporary file (never half-written); eviction takes
an exclusive `flock` on the mirror, reads hold a shared one from the check that their
objects are present until the read ends, so no object disappears under a reader.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import tempfile
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pyarrow.fs as pafs

from schemas.cache_layout import H_CELLS
from store.file_lock import EXCLUSIVE, SHARED, flocked
from store.object_store import (
    StoreURL,
    check_location,
    filesystem,
    is_url,
    parse_url,
    read_bytes,
)

DEFAULT_LIMIT_BYTES = 20 * 2**30
LOCK = ".lock"
ENV_DIR = "M3GD_SHARD_CACHE"
"""Environment variable naming the mirror's parent directory (default: the temp dir)."""


def default_root(url: StoreURL) -> Path:
    """Mirror directory for `url`: $M3GD_SHARD_CACHE or the temp dir, one per URL."""
    parent = Path(os.environ.get(ENV_DIR) or Path(tempfile.gettempdir()) / "m3gd-shards")
    return parent / hashlib.sha256(str(url).encode()).hexdigest()[:16]


def chunk_keys(meta: dict[str, Any], frames: list[int]) -> list[str]:
    """Keys (relative to the array) of the outer chunks (shards) holding views `frames` of a
    Zarr v3 array with metadata `meta` (regular grid; default or v2 key encoding)."""
    shape = meta["shape"]
    chunks = meta["chunk_grid"]["configuration"]["chunk_shape"]
    enc = meta.get("chunk_key_encoding", {"name": "default"})
    default = enc.get("name") == "default"
    sep = enc.get("configuration", {}).get("separator", "/" if default else ".")
    rest = [range(-(-n // c)) for n, c in zip(shape[1:], chunks[1:], strict=True)]
    keys = []
    for first in sorted({f // chunks[0] for f in frames}):
        for idx in itertools.product([first], *rest):
            key = sep.join(str(i) for i in idx)
            keys.append(f"c{sep}{key}" if default else key)
    return keys


def stored_names(names: list[str]) -> list[str]:
    """Arrays a clip read of `names` touches: packet features (h, h_rows) are h_cells + g."""
    out = [s for n in names for s in ((H_CELLS, "g") if n in ("h", "h_rows") else (n,))]
    return list(dict.fromkeys(out))


class ShardCache:
    """A bounded read-through mirror of the objects below `url` in directory `root`.

    `stats` counts, per process: `hits` and `misses` (shard objects a read needed that were
    present or had to be fetched), `gets` (objects fetched, metadata included), `bytes`
    fetched, `evicted` shard objects.
    """

    def __init__(self, url: StoreURL, root: Path, limit_bytes: int = DEFAULT_LIMIT_BYTES
                 ) -> None:
        self.url, self.root, self.limit_bytes = url, root, limit_bytes
        self.stats: Counter[str] = Counter()
        self._fs: pafs.FileSystem | None = None
        self._absent: set[str] = set()
        self._meta: dict[str, dict[str, Any]] = {}
        root.mkdir(parents=True, exist_ok=True)

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_fs": None}

    @property
    def fs(self) -> pafs.FileSystem:
        """The S3 filesystem (made on first use in each process)."""
        if self._fs is None:
            self._fs = filesystem()
        return self._fs

    def fetch(self, rel: str) -> Path | None:
        """Local path of object `rel`, fetched whole (one GET) if not yet present; None when
        the store has no such object (e.g. a chunk never written: fill value)."""
        local = self.root / rel
        if local.exists():
            return local
        if rel in self._absent:
            return None
        data = read_bytes(self.fs, self.url, rel)
        self.stats["gets"] += 1
        if data is None:
            self._absent.add(rel)
            return None
        self.stats["bytes"] += len(data)
        local.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=local.parent, prefix=".part-")
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        os.replace(tmp, local)  # whole or not at all
        return local

    def array_meta(self, array_rel: str) -> dict[str, Any]:
        """zarr.json of the array at `array_rel` (fetched once)."""
        if array_rel not in self._meta:
            path = self.fetch(f"{array_rel}/zarr.json")
            if path is None:
                raise FileNotFoundError(f"{self.url.url(array_rel)}/zarr.json: no such array")
            self._meta[array_rel] = json.loads(path.read_text())
        return self._meta[array_rel]

    def view_objects(self, group_rel: str, names: list[str], frames: list[int]) -> list[str]:
        """Object keys (relative to the URL) a read of views `frames` of arrays `names` of the
        cache group `group_rel` touches."""
        rels = []
        for name in stored_names(names):
            array = f"{group_rel}/{name}"
            rels += [f"{array}/{k}" for k in chunk_keys(self.array_meta(array), frames)]
        return rels

    @contextmanager
    def holding(self, rels: list[str]) -> Iterator[None]:
        """Objects `rels` present in the mirror (fetched as needed) until the block ends."""
        fetched = 0
        while True:
            missing = [r for r in rels if not (self.root / r).exists() and r not in self._absent]
            for rel in missing:
                fetched += self.fetch(rel) is not None
            if missing:
                with self._lock(EXCLUSIVE):
                    self._evict(keep=set(rels))
            with self._lock(SHARED):
                if all((self.root / r).exists() for r in rels if r not in self._absent):
                    self._count(rels, fetched)
                    yield
                    return

    def _count(self, rels: list[str], fetched: int) -> None:
        present = [r for r in rels if r not in self._absent]
        self.stats["misses"] += fetched
        self.stats["hits"] += len(present) - fetched
        for rel in present:
            os.utime(self.root / rel)  # recency for LRU

    @contextmanager
    def _lock(self, mode: int) -> Iterator[None]:
        with flocked(self.root / LOCK, mode):
            yield

    def shard_files(self) -> list[tuple[float, int, Path]]:
        """(mtime, size, path) of every shard object in the mirror (not metadata)."""
        out = []
        for dirpath, _, files in os.walk(self.root):
            if "c" not in Path(dirpath).relative_to(self.root).parts:
                continue  # chunk keys live below a "c" directory (default encoding)
            for name in files:
                if not name.startswith(".part-"):
                    path = Path(dirpath, name)
                    st = path.stat()
                    out.append((st.st_mtime, st.st_size, path))
        return out

    def _evict(self, keep: set[str]) -> None:
        """Remove least recently used shard objects (not `keep`) beyond the byte limit."""
        files = sorted(self.shard_files())
        total = sum(size for _, size, _ in files)
        for _, size, path in files:
            if total <= self.limit_bytes:
                break
            if str(path.relative_to(self.root)) in keep:
                continue
            path.unlink(missing_ok=True)
            total -= size
            self.stats["evicted"] += 1


def open_remote(location: str | Path, root: Path | None = None,
                limit_bytes: int = DEFAULT_LIMIT_BYTES) -> ShardCache | None:
    """A checked ShardCache for an `s3://` output location, or None for a local path."""
    if not is_url(location):
        return None
    url = parse_url(location)
    check_location(filesystem(), url)  # before the mirror folder is made
    return ShardCache(url, root or default_root(url), limit_bytes)
