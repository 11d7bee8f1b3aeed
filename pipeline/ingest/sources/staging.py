"""Recordings on object storage: a mission at `s3://bucket/prefix` is fetched to worker-local
scratch for the item that reads it, and removed when the item ends.

Why whole files and not ranged reads: ingest reads every message of the image and LiDAR
topics, i.e. nearly every byte of the bags (or of the HF layout's stores and JPEG folders),
and the readers (rosbags, zarr, OpenCV) work on local files; ranged reads would save no bytes
and cost a request per chunk. The packets stage reads a recording's sweeps again and stages
the mission the same way. Disk use is bounded per item: a mission larger than the limit
(`$M3GD_SCRATCH_BYTES`, default 256 GiB) or than the free space of the scratch folder
(`$M3GD_SCRATCH`, default the temp dir) is refused with one line before anything is fetched.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pyarrow.fs as pafs

from pipeline.ingest.sources.base import DETECT_DEPTH, name_order
from pipeline.ingest.sources.registry import claiming
from pipeline.run.scratch import limit_bytes, scratch_root
from pipeline.run.store_sync import client, fetch
from store.object_store import (
    StorageError,
    StoreURL,
    check_location,
    filesystem,
    is_url,
    parse_url,
    reason,
    where,
)


def list_mission(fs: pafs.FileSystem, url: StoreURL) -> list[pafs.FileInfo]:
    """Every object below the mission's prefix (files only, sorted by key)."""
    check_location(fs, url)
    try:
        found = fs.get_file_info(pafs.FileSelector(url.key(""), recursive=True,
                                                   allow_not_found=True))
    except OSError as err:
        raise StorageError(f"{where(url)}: {reason(err)}") from err
    files = sorted((f for f in found if f.type == pafs.FileType.File), key=lambda f: f.path)
    if not files:
        raise StorageError(f"{where(url)}: no objects below this prefix (no mission)")
    return files


def mission_identity(location: Path) -> list[dict[str, Any]]:
    """Identity (path, size, mtime_ns) of a mission on S3 (listing only), chosen by the source
    that claims the listing as for a local mission (`RecordingSource.identity`); a folder's
    size is its objects' total and its mtime their latest."""
    url = parse_url(location)
    files = list_mission(filesystem(), url)
    base = url.key("") + "/"
    entries = remote_entries([(f.path[len(base):], f.size,
                               int(f.mtime.timestamp() * 1e9) if f.mtime else 0)
                              for f in files if f.path.startswith(base)])  # fmt: skip
    names = sorted(entries, key=name_order)
    top = [n for n in names if n.rstrip("/").count("/") < DETECT_DEPTH]
    return [{"path": f"s3://{base}{n.rstrip('/')}", "size": entries[n][0],
             "mtime_ns": entries[n][1], "sha256": None}
            for n in claiming(top).identity(names)]  # fmt: skip


def remote_entries(files: list[tuple[str, int, int]]) -> dict[str, tuple[int, int]]:
    """(size, mtime_ns) by listing name from (relative key, size, mtime_ns) of every object:
    each folder above an object is listed too (name ending "/": total size, latest mtime)."""
    out: dict[str, tuple[int, int]] = {}
    for key, size, mtime in files:
        out[key] = (size, mtime)
        parts = key.split("/")[:-1]
        for i in range(1, len(parts) + 1):
            folder = "/".join(parts[:i]) + "/"
            total, latest = out.get(folder, (0, 0))
            out[folder] = (total + size, max(latest, mtime))
    return out


@contextmanager
def staged(location: Path) -> Iterator[Path]:
    """The mission folder `location` itself when local; for `s3://…` a local copy in
    scratch (same folder name), removed when the block ends, whatever happens."""
    if not is_url(location):
        yield Path(location)
        return
    url = parse_url(location)
    fs = filesystem()
    files = list_mission(fs, url)
    total = sum(f.size for f in files)
    root = scratch_root()
    root.mkdir(parents=True, exist_ok=True)
    free = shutil.disk_usage(root).free
    if total > min(limit_bytes(), free):
        raise StorageError(f"{url}: the mission's {total / 1e9:.2f} GB exceed the scratch "
                           f"limit ({min(limit_bytes(), free) / 1e9:.2f} GB free or allowed "
                           f"in {root}); set M3GD_SCRATCH / M3GD_SCRATCH_BYTES")
    tmp = Path(tempfile.mkdtemp(prefix="m3gd-stage-", dir=root))
    mission = tmp / url.prefix.rsplit("/", 1)[-1]
    base = url.key("") + "/"
    try:
        s3 = client() if files else None
        for info in files:
            fetch(s3, info.path, mission / info.path[len(base):])  # one GET, in blocks
        yield mission
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
