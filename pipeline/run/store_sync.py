"""Whole-object transfers between an output on object storage and a local scratch copy.

An item of a run whose output_dir is `s3://bucket/prefix` works on a worker-local scratch
folder laid out exactly like a local output (`pull` fetches the objects it reads), and its
new or rewritten files are then uploaded as whole objects and the objects of the files it
removed are deleted (`push`). An item that removes a Zarr array or recreates it with
another layout (`layouts`: shape, data type, chunk grid, key encoding, codecs) downloaded
only the chunk objects it reads; every other object of that array seen on the store when
the item started (`Seen`) is deleted too (`stale`), unless it changed meanwhile: an old
layout's chunk left on the store would be read as a chunk of the new one. A PUT on S3 makes an
object appear whole or not at all (a multipart upload too, on completion), so a shard object
is never seen half-written; `push` uploads the shard done-marks (`cache_done/`) last, so a
killed push leaves at most shards without marks, which a rerun redoes.

Only the objects `keep` accepts are fetched; the listing (one LIST per 1000 keys) is per
prefix, so an item lists its own recording's keys, not the whole output. Listing and uploads
go through Arrow's S3 filesystem (as the read side); a fetch is one GET through boto3
(Arrow's input stream sends a HEAD before each GET: twice the requests).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import pyarrow.fs as pafs

from schemas.layout import DONE_DIRNAME
from store.object_store import (
    CONNECT_TIMEOUT_S,
    REQUEST_TIMEOUT_S,
    StorageError,
    StoreURL,
    endpoint,
    reason,
    region,
    where,
)

COPY_BLOCK = 8 << 20
Version = tuple[int, int]
Seen = dict[str, Version]
"""rel path -> (size, mtime_ns) of each object a listing found on the store."""
Layout = tuple[str, ...]
"""What decides where and how an array's chunks are stored (JSON of each part)."""
LAYOUT_KEYS = ("shape", "data_type", "chunk_grid", "chunk_key_encoding", "codecs")
"""(size, mtime_ns) of a local file: what tells a rewritten file from a pulled one. A pulled
file gets mtime 0, so a rewrite is seen even within the file system's timestamp granularity
(a jiffy for many: a few ms) and at the same size."""


def list_files(fs: pafs.FileSystem, url: StoreURL, rel: str) -> list[pafs.FileInfo]:
    """Every object at or below `rel` (relative to `url`), sorted by key; [] when none."""
    key = url.key(rel)
    try:
        found = fs.get_file_info(pafs.FileSelector(key, recursive=True, allow_not_found=True))
        if not found:  # `rel` may name one object rather than a prefix
            single = fs.get_file_info(key)
            found = [single] if single.type == pafs.FileType.File else []
    except OSError as err:
        raise StorageError(f"{where(url.url(rel))}: {reason(err)}") from err
    return sorted((f for f in found if f.type == pafs.FileType.File), key=lambda f: f.path)


def rel_of(url: StoreURL, info: pafs.FileInfo) -> str:
    """The key of `info` relative to `url` (the output's path of the object)."""
    base = url.key("")
    return str(info.path[len(base):]).lstrip("/")


def client() -> Any:
    """A boto3 S3 client configured from the environment like `store.object_store`."""
    import boto3
    from botocore.config import Config

    conf = Config(connect_timeout=CONNECT_TIMEOUT_S, read_timeout=REQUEST_TIMEOUT_S,
                  retries={"max_attempts": 3, "mode": "standard"})
    return boto3.client("s3", endpoint_url=endpoint(), region_name=region(), config=conf)


def fetch(s3: Any, key: str, target: Path) -> int:
    """Copy the object `key` (bucket/...) to `target` in blocks with one GET (Arrow's input
    stream sends a HEAD first); return its bytes."""
    from botocore.exceptions import BotoCoreError, ClientError

    bucket, _, name = key.partition("/")
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        body = s3.get_object(Bucket=bucket, Key=name)["Body"]
        with target.open("wb") as dst:
            shutil.copyfileobj(body, dst, COPY_BLOCK)
    except (BotoCoreError, ClientError, OSError) as err:
        raise StorageError(f"{where('s3://' + key)}: {reason(err)}") from err
    os.utime(target, ns=(0, 0))  # any rewrite gets a later mtime, even of the same size
    return target.stat().st_size


def version_of(info: pafs.FileInfo) -> Version:
    """(size, mtime_ns) of a listed object."""
    return (info.size or 0, info.mtime_ns or 0)


def pull(fs: pafs.FileSystem, url: StoreURL, local: Path, prefixes: Iterable[str],
         keep: Callable[[str], bool] = lambda rel: True, seen: Seen | None = None) -> int:
    """Fetch every object below the `prefixes` of `url` that `keep(rel)` accepts into the
    same relative path under `local` (listed with `fs`, one GET each); return the bytes.
    Every listed object, fetched or not, is recorded in `seen` when given."""
    total = 0
    s3 = None
    for prefix in prefixes:
        for info in list_files(fs, url, prefix):
            rel = rel_of(url, info)
            if seen is not None:
                seen[rel] = version_of(info)
            if keep(rel):
                s3 = s3 or client()
                total += fetch(s3, info.path, local / rel)
    return total


def snapshot(local: Path) -> dict[str, Version]:
    """rel path -> (size, mtime_ns) of every file under `local`, leaving out the hidden
    temporaries of atomic writes (`.<name>.<pid>.tmp`)."""
    out: dict[str, Version] = {}
    for path in local.rglob("*"):
        if path.is_file() and not (path.name.startswith(".") and path.name.endswith(".tmp")):
            st = path.stat()
            out[path.relative_to(local).as_posix()] = (st.st_size, st.st_mtime_ns)
    return out


def changed(before: dict[str, Version], after: dict[str, Version]) -> list[str]:
    """Files new or rewritten between two snapshots, sorted."""
    return sorted(rel for rel, version in after.items() if before.get(rel) != version)


def layouts(local: Path) -> dict[str, Layout]:
    """Folder (rel path) -> layout of every Zarr v3 array under `local` (its `zarr.json`)."""
    out: dict[str, Layout] = {}
    for meta in local.rglob("zarr.json"):
        try:
            doc = json.loads(meta.read_bytes())
        except (OSError, ValueError):
            continue  # not metadata m3gd can read: not an array it replaces
        if isinstance(doc, dict) and doc.get("node_type") == "array":
            key = meta.parent.relative_to(local).as_posix()
            out[key] = tuple(json.dumps(doc.get(k), sort_keys=True) for k in LAYOUT_KEYS)
    return out


def replaced(before: dict[str, Layout], after: dict[str, Layout]) -> list[str]:
    """Arrays (folders) removed or recreated with another layout between two `layouts`."""
    return sorted(a for a, lay in before.items() if after.get(a) != lay)


def stale(seen: Seen, arrays: Iterable[str], kept: Iterable[str]) -> list[str]:
    """The objects in `seen` below the `arrays` folders that are not among `kept` (the files
    the item holds after its run), sorted: what remains on the store of replaced arrays."""
    prefixes = tuple(a + "/" for a in arrays)
    keep = set(kept)
    return sorted(r for r in seen if r.startswith(prefixes) and r not in keep)


def delete_unchanged(fs: pafs.FileSystem, url: StoreURL, rels: Iterable[str],
                     seen: Seen) -> int:
    """Delete each object of `rels` still at its version in `seen` (another item's upload
    since then is kept); return how many were deleted."""
    rels = sorted(rels)
    now: Seen = {}
    for folder in sorted({r.rsplit("/", 1)[0] for r in rels}):
        now.update((rel_of(url, i), version_of(i)) for i in list_files(fs, url, folder))
    gone = [r for r in rels if r in now and now[r] == seen.get(r)]
    for rel in gone:
        delete(fs, url, rel)
    return len(gone)


def upload_order(rels: Iterable[str]) -> list[str]:
    """`rels` with the done-marks (under `cache_done/`) last: a mark on the store promises
    that every object of its shard is there."""
    rels = sorted(rels)
    marks = [r for r in rels if r.startswith(DONE_DIRNAME + "/")]
    return [r for r in rels if r not in set(marks)] + marks


def put_file(fs: pafs.FileSystem, url: StoreURL, local: Path, rel: str) -> int:
    """Upload `local/rel` as the whole object `rel` below `url`; return its bytes."""
    source = local / rel
    try:
        with source.open("rb") as src, fs.open_output_stream(url.key(rel)) as dst:
            shutil.copyfileobj(src, dst, COPY_BLOCK)
    except OSError as err:
        raise StorageError(f"{where(url.url(rel))}: {reason(err)}") from err
    return source.stat().st_size


def put_bytes(fs: pafs.FileSystem, url: StoreURL, rel: str, data: bytes) -> None:
    """Write `data` as the whole object `rel` below `url` (one PUT)."""
    try:
        with fs.open_output_stream(url.key(rel)) as dst:
            dst.write(data)
    except OSError as err:
        raise StorageError(f"{where(url.url(rel))}: {reason(err)}") from err


def delete(fs: pafs.FileSystem, url: StoreURL, rel: str) -> None:
    """Delete the object `rel` below `url` (gone already: nothing to do)."""
    try:
        fs.delete_file(url.key(rel))
    except FileNotFoundError:
        pass
    except OSError as err:
        raise StorageError(f"{where(url.url(rel))}: {reason(err)}") from err


def push(fs: pafs.FileSystem, url: StoreURL, local: Path, rels: Iterable[str],
         gone: Iterable[str] = (), leftovers: Iterable[str] = (), seen: Seen | None = None,
         ) -> int:
    """Upload the files `rels` under `local`, delete the objects `gone` (files the item
    removed) and the `leftovers` still as `seen` (objects of arrays it replaced), the
    done-marks last; return the bytes sent."""
    order = upload_order(rels)
    marks = [r for r in order if r.startswith(DONE_DIRNAME + "/")]
    sent = sum(put_file(fs, url, local, rel) for rel in order[:len(order) - len(marks)])
    for rel in gone:
        delete(fs, url, rel)
    delete_unchanged(fs, url, set(leftovers) - set(gone), seen or {})
    return sent + sum(put_file(fs, url, local, rel) for rel in marks)
