"""Runs whose output_dir is on object storage (`s3://bucket/prefix`): items on scratch.

Each item runs on the worker that got it, against a fresh worker-local scratch folder laid
out like a local output: first the objects the item reads (declared by its stage,
`pipeline.run.reads.StoreReads`) are fetched into it,
then the stage's own `run` works there exactly as on a local output, then every file the
item created or rewrote is uploaded as a whole object, the shard done-marks last
(`pipeline.run.store_sync`), and the folder is removed. Workers share nothing but the
store and the scheduler. Recordings synthesized into the output are read from the store
like configured `s3://` recordings (staged per item, `pipeline.ingest.sources.staging`).

The driver keeps the manifest on the store (read once, rewritten as one object after every
finished item) and plans the stages that look at earlier outputs (`StoreReads.plan`) over a
scratch copy of the metadata they read. Invariants as on a local output: an item counts as
done only once the driver recorded it in the manifest, which happens after its upload
ended; an encode or packets shard only once its done-mark is on the store, uploaded after
its arrays. A killed run therefore leaves objects a rerun overwrites or skips, never a shard
that looks complete and is not.
"""

from __future__ import annotations

import functools
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from pipeline.run.checksums import Dependants, forget_files, verify_files
from pipeline.run.reads import CHUNK, StoreReads
from pipeline.run.scratch import scratch_root
from pipeline.run.stage import Item, ItemResult, Stage
from pipeline.run.store_sync import (
    Seen,
    changed,
    layouts,
    list_files,
    pull,
    push,
    rel_of,
    replaced,
    snapshot,
    stale,
)
from schemas.atomic_io import checksum_path, sidecar_text, written_by
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.layout import (
    CACHE_DIRNAME,
    CLIPS_FILENAME,
    DONE_DIRNAME,
    INDEX_DIRNAME,
    MANIFEST_FILENAME,
    STATS_DIRNAME,
)
from schemas.manifest import RunManifest
from schemas.missions import recordings
from store.object_store import StoreURL, check_location, filesystem, is_url, parse_url, read_bytes

RunFn = Callable[[M3GDConfig, Item], ItemResult]


def scratch_config(cfg: M3GDConfig, folder: Path) -> M3GDConfig:
    """`cfg` on the local `folder` instead of its `s3://` output; recordings it synthesized
    into the output are named by their URLs (read from the store, not from `folder`)."""
    ingest = cfg.ingest
    if not ingest.recordings:
        ingest = ingest.model_copy(update={"recordings": [str(p) for p in recordings(cfg)]})
    return cfg.model_copy(update={"output_dir": folder, "ingest": ingest})


@contextmanager
def scratch_folder(prefix: str) -> Iterator[Path]:
    """A fresh folder under the worker's scratch root, removed when the block ends."""
    root = scratch_root()
    root.mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix=prefix, dir=root))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run_on_store(store: StoreReads, run: RunFn, cfg: M3GDConfig, item: Item) -> ItemResult:
    """Run one item of a stage reading `store` for an output on the store: fetch what it
    reads to scratch, run it there, upload what it wrote and delete the objects of the files
    it removed, and every other object of the arrays it removed or recreated with another
    layout (done-marks last); picklable with functools.partial."""
    url = parse_url(cfg.output_dir)
    fs = filesystem()
    reads = store.for_item(item.key)
    seen: Seen = {}
    with scratch_folder("m3gd-item-") as folder:
        fetched = pull(fs, url, folder, reads.of(item.key),
                       functools.partial(reads.keep, item.key), seen)
        before, arrays = snapshot(folder), layouts(folder)
        result = run(scratch_config(cfg, folder), item)
        after = snapshot(folder)
        leftovers = stale(seen, replaced(arrays, layouts(folder)), after)
        sent = push(fs, url, folder, changed(before, after), sorted(set(before) - set(after)),
                    leftovers, seen)
    result.detail["store_bytes"] = {"fetched": fetched, "uploaded": sent}
    return result


def item_runner(stage: Stage, cfg: M3GDConfig) -> RunFn:
    """What the executor runs per item of `stage`: its `run`, or `run_on_store` for an
    s3:// output."""
    if not is_url(cfg.output_dir):
        return functools.partial(run_as_writer, stage.name, stage.run)
    return functools.partial(run_as_writer, stage.name,
                             functools.partial(run_on_store, stage.store, stage.run))


def run_as_writer(stage: str, run: RunFn, cfg: M3GDConfig, item: Item) -> ItemResult:
    """`run(cfg, item)` with the checksum sidecars it writes naming `stage` and the item as
    their writer (`schemas.atomic_io.written_by`)."""
    with written_by(stage, item.key.format()):
        return run(cfg, item)


GUARDED_PREFIXES = (INDEX_DIRNAME, STATS_DIRNAME, CACHE_DIRNAME, DONE_DIRNAME, CLIPS_FILENAME,
                    checksum_path(Path(CLIPS_FILENAME)).as_posix())
"""Where the tables, metadata files, their checksum sidecars and the done-marks of an output
lie (`pipeline.run.checksums.guarded_files`); their chunks are not fetched."""


class StoreOutput:
    """The driver's view of an output on the store: manifest and planning metadata."""

    def __init__(self, location: Path | str) -> None:
        self.url: StoreURL = parse_url(location)
        self.fs = filesystem()

    def check(self) -> None:
        """StorageError (one line naming the URL) unless the bucket can be reached."""
        check_location(self.fs, self.url)

    def read_manifest(self) -> RunManifest | None:
        """The manifest object, or None when there is none yet."""
        data = read_bytes(self.fs, self.url, MANIFEST_FILENAME)
        if data is None:
            return None
        return RunManifest.from_json(data.decode(), self.url.url(MANIFEST_FILENAME))

    def write_manifest(self, manifest: RunManifest) -> None:
        """Replace the manifest object and its checksum sidecar (as a local output has)."""
        from pipeline.run.store_sync import put_bytes

        data = manifest.to_json().encode()
        put_bytes(self.fs, self.url, MANIFEST_FILENAME, data)
        sidecar = checksum_path(Path(MANIFEST_FILENAME)).name
        put_bytes(self.fs, self.url, sidecar, sidecar_text(MANIFEST_FILENAME, data).encode())

    def forget_damaged(self, manifest: RunManifest, dependants: Dependants) -> list[str]:
        """Check the uploaded tables and metadata files against their uploaded checksum
        sidecars as a local output's are (`verify_files` over a scratch copy of them, the
        done-marks and the cache's `zarr.json`) and forget, in `manifest` and the done-marks
        on the store, what the next run must redo (`forget_files`): the done-marks it
        removed are deleted, the metadata it rewrote uploaded, the objects of an array it
        removed deleted. Returns one line per damaged object, named by its URL."""
        with self.local_copy(GUARDED_PREFIXES) as folder:
            _, damaged = verify_files(folder)
            if not damaged:
                return []
            before = snapshot(folder)
            forget_files(folder / CACHE_DIRNAME, manifest, damaged, dependants)
            after = snapshot(folder)
            gone = sorted(set(before) - set(after))
            arrays = {str(Path(r).parent) for r in gone
                      if r.startswith(CACHE_DIRNAME + "/") and r.endswith("/zarr.json")
                      and len(Path(r).parts) == 5}
            chunks = [rel_of(self.url, f) for a in sorted(arrays)
                      for f in list_files(self.fs, self.url, a)]
            push(self.fs, self.url, folder, changed(before, after), [*gone, *chunks])
            return [f.line().replace(f"{folder}/", self.url.url("").rstrip("/") + "/")
                    for f in damaged]

    @contextmanager
    def local_copy(self, prefixes: tuple[str, ...]) -> Iterator[Path]:
        """A scratch folder holding the metadata objects below `prefixes` (no chunks)."""
        with scratch_folder("m3gd-plan-") as folder:
            pull(self.fs, self.url, folder, prefixes, lambda rel: CHUNK.match(rel) is None)
            yield folder

    @contextmanager
    def plan_config(self, cfg: M3GDConfig, stage: Stage) -> Iterator[M3GDConfig]:
        """The config `stage.plan` should see: `cfg` itself, or on a scratch copy of the
        metadata the plan reads (`stage.store.plan`)."""
        prefixes = stage.store.plan
        if prefixes is None:
            yield cfg
            return
        with self.local_copy(prefixes) as folder:
            yield cfg.model_copy(update={"output_dir": folder})


@contextmanager
def local_view(output_dir: Path, prefixes: tuple[str, ...]) -> Iterator[Path]:
    """`output_dir` itself when local; for an `s3://` output a scratch copy of the metadata
    objects below `prefixes` (for the driver's checks and reports after a run)."""
    if not is_url(output_dir):
        yield output_dir
        return
    with StoreOutput(output_dir).local_copy(prefixes) as folder:
        yield folder


def check_output(output_dir: Path) -> None:
    """StorageError (one line naming the URL) when an `s3://` output cannot be reached
    (endpoint, bucket, credentials); nothing for a local one."""
    if is_url(output_dir):
        StoreOutput(output_dir).check()


class LocalOnly(DataError):
    """A command that reads or writes a local output folder was given an `s3://` one."""


def refuse_on_store(output_dir: Path, command: str, needs: str = "") -> None:
    """LocalOnly (one line naming the URL) when `output_dir` is on the store: `command`
    works on a local output folder only (`needs`: the options that would let it run)."""
    if is_url(output_dir):
        what = f"pass {needs}" if needs else "copy the output to a local folder"
        raise LocalOnly(f"{parse_url(output_dir)}: `m3gd {command}` works on a local output "
                        f"folder only, not on object storage; {what}")
