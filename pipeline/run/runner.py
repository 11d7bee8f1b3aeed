"""Run the stage graph: skip what is current, retry what fails, record what finished.

The driver process owns the run manifest (single writer); workers only write
their own outputs. An item whose cache key is recorded as done is skipped; a
forced stage gets a new generation, which changes the keys of its items and of
everything downstream so their shard marks no longer match either.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.text import Text

from pipeline.run.checksums import forget_files, verify_files
from pipeline.run.executors import DaskExecutor, LocalExecutor
from pipeline.run.keys import CROSS_PREFIX, ItemKey
from pipeline.run.lock import held_output
from pipeline.run.progress import LineProgress, make_progress
from pipeline.run.remote import StoreOutput, item_runner
from pipeline.run.stage import Item, Stage, ancestors, downstream_of, topological, unreadable_output
from schemas.config import M3GDConfig, config_hash
from schemas.layout import CACHE_DIRNAME
from schemas.manifest import RunManifest, read_manifest, write_manifest
from store.object_store import is_url

log = logging.getLogger(__name__)

PACKAGES = ("m3gd", "numpy", "torch", "zarr", "pyarrow", "rosbags", "open3d-cpu", "dask")


@dataclass
class StageSummary:
    """Per-stage counts and wall time of one run."""

    name: str
    items: int = 0
    done: int = 0
    skipped: int = 0
    rejected: int = 0
    failed: dict[str, str] = field(default_factory=dict)
    """Formatted item key -> error line."""
    failed_recordings: set[str] = field(default_factory=set)
    """Recordings with a failed item (later stages skip them)."""
    seconds: float = 0.0


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that shape outputs."""
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "missing"
    return out


def new_manifest(cfg: M3GDConfig) -> RunManifest:
    """A fresh manifest for `cfg`."""
    versions = package_versions()
    return RunManifest(config_hash(cfg), versions.get("m3gd", "unknown"), versions)


def _effective(item: Item, generation: int, lineage: str = "") -> Item:
    """The item with its cache key salted by the stage generation (bumped by --force) and
    by `lineage`, the keys of the upstream items it reads (see `Lineage`)."""
    if generation == 0 and not lineage:
        return item
    salted = hashlib.sha256(f"{item.cache_key}:{generation}:{lineage}".encode()).hexdigest()
    return Item(item.key, salted[:32])


class Lineage:
    """Effective cache keys of the items planned so far, by stage and recording.

    An item is current only if everything it reads is: its effective key includes the
    effective keys of its upstream stages' items of the same recording (and of their
    cross-recording items; a cross-recording item includes all of them). So a recording
    re-ingested because a bag changed is selected, encoded and packed again instead of
    being reported up to date over arrays the new ingest replaced.
    """

    def __init__(self) -> None:
        # stage -> group -> ["<formatted key>=<cache key>"]; a group is a recording's name or
        # the formatted key of a cross-recording item ('_<name>', sorted as a string)
        self.keys: dict[str, dict[str, list[str]]] = {}

    def add(self, stage: str, items: list[Item]) -> None:
        """Record the effective items of `stage`."""
        table: dict[str, list[str]] = {}
        for item in items:
            table.setdefault(_group(item.key), []).append(f"{item.key.format()}={item.cache_key}")
        self.keys[stage] = table

    def of(self, upstream: set[str]) -> Callable[[ItemKey], str]:
        """item key -> hash of the upstream keys that item depends on (cached per recording)."""
        memo: dict[str | None, str] = {}

        def lineage(key: ItemKey) -> str:
            rec = key.recording  # None: a cross-recording item, which reads every group
            if rec not in memo:
                parts: list[str] = []
                for stage in sorted(upstream):
                    table = self.keys.get(stage, {})
                    groups = sorted(table) if rec is None else [rec, *(
                        g for g in sorted(table) if g.startswith(CROSS_PREFIX))]
                    parts.extend(f"{stage}:{k}" for g in groups for k in sorted(table.get(g, [])))
                memo[rec] = hashlib.sha256("\n".join(parts).encode()).hexdigest() if parts else ""
            return memo[rec]

        return lineage


def _group(key: ItemKey) -> str:
    """The lineage group of an item: its recording, or its formatted key if cross-recording."""
    return key.format() if key.recording is None else key.recording


def runnable(items: list[Item], failed: set[str], recordings: set[str]) -> list[Item]:
    """The items of a stage that run: none of a failed recording, and no cross-recording item
    when every recording of the run failed (it would build an empty cache or clip index that
    looks complete; it is built on the run that has a recording to build it over)."""
    left = [i for i in items if i.key.recording not in failed]
    if failed and recordings <= failed:
        skipped = [i.key.format() for i in left if i.key.is_cross]
        if skipped:
            log.warning("%s: not run, every recording failed", ", ".join(skipped))
        left = [i for i in left if not i.key.is_cross]
    return left


def make_executor(cfg: M3GDConfig, local: bool) -> LocalExecutor | DaskExecutor:
    """The executor the config (or --local) asks for."""
    if local or (cfg.dag.executor == "local" and not cfg.dag.scheduler):
        return LocalExecutor()
    return DaskExecutor(cfg.dag.workers, cfg.dag.scheduler, cfg.dag.dashboard)


class Runner:
    """Runs a list of stages for one configuration and output directory."""

    def __init__(self, cfg: M3GDConfig, stages: list[Stage], progress: bool = True,
                 console: Console | None = None) -> None:
        """progress: print a bar per stage on `console` (the caller's, so log lines and bars
        share it; default a new one on stderr)."""
        self.cfg = cfg
        self.stages = topological(stages)
        self.out: Path = cfg.output_dir
        self.progress = progress
        self.console = console or Console(stderr=True)
        self.store = StoreOutput(self.out) if is_url(self.out) else None
        self.pending = False  # items marked done since the manifest was last written
        self.written_at = -math.inf  # time.monotonic() of that write

    def run(self, executor: LocalExecutor | DaskExecutor, force: list[str] | None = None,
            only: list[str] | None = None, locked: bool = False) -> list[StageSummary]:
        """Run every stage (or `only` those) under the output lock; return summaries.

        locked: the caller already holds the output lock (`pipeline.run.lock.acquire_output`).
        """
        with contextlib.nullcontext() if locked else held_output(self.out):
            manifest = self._read_manifest() or new_manifest(self.cfg)
            if not self.store:
                self._forget_damaged(manifest)
            manifest.config_hash = config_hash(self.cfg)
            generations = self._bump(manifest, force or [])
            self._write_manifest(manifest)
            failed_recordings: set[str] = set()
            recordings: set[str] = set()  # every recording an item was planned for so far
            summaries = []
            lineage = Lineage()
            wanted = [s.name for s in self.stages if not only or s.name in only]
            for stage in self.stages:
                if not wanted:
                    break
                items = self._plan(stage, generations, lineage)
                recordings |= {i.key.recording for i in items if i.key.recording is not None}
                if stage.name not in wanted:
                    continue  # planned only for the keys of the stages after it
                wanted.remove(stage.name)
                left = runnable(items, failed_recordings, recordings)
                summary = self._run_stage(stage, left, executor, manifest, failed_recordings,
                                          blocked=len(items) - len(left))
                summaries.append(summary)
                failed_recordings |= summary.failed_recordings
            return summaries

    def _read_manifest(self) -> RunManifest | None:
        """The output's manifest (local file or object on the store), None if there is none."""
        return self.store.read_manifest() if self.store else read_manifest(self.out)

    def _forget_damaged(self, manifest: RunManifest) -> None:
        """Forget the items whose tables or metadata files no longer match their checksum
        sidecars (damaged, cut or missing), and their dependants: logged, and redone."""
        _, damaged = verify_files(self.out)
        for file in damaged:
            log.warning("%s", file.line())
        forget_files(self.out / CACHE_DIRNAME, manifest, damaged,
                     lambda name: downstream_of(self.stages, name))

    def _write_manifest(self, manifest: RunManifest) -> None:
        """Replace the output's manifest (atomic rename locally, one PUT on the store)."""
        if self.store:
            self.store.write_manifest(manifest)
        else:
            write_manifest(manifest, self.out)
        self.pending, self.written_at = False, time.monotonic()

    def _record(self, manifest: RunManifest) -> None:
        """After an item was marked done: write the manifest now (local: every item, a
        rename is cheap) or, on the store, once `dag.manifest_every_s` passed since the last
        write (the stage's end writes what is pending)."""
        self.pending = True
        every = self.cfg.dag.manifest_every_s if self.store else 0.0
        if time.monotonic() - self.written_at >= every:
            self._write_manifest(manifest)

    def _bump(self, manifest: RunManifest, force: list[str]) -> dict[str, int]:
        """Increase the generation of forced stages and their downstream ones."""
        gens = manifest.stages.get("_generations")
        table = dict(gens.items) if gens else {}
        for name in force:
            for hit in downstream_of(self.stages, name):
                table[hit] = str(int(table.get(hit, "0")) + 1)
                manifest.forget(hit)
        manifest.forget("_generations")
        for key, value in table.items():
            manifest.mark_done("_generations", key, value)
        return {k: int(v) for k, v in table.items()}

    def _plan(self, stage: Stage, generations: dict[str, int], lineage: Lineage) -> list[Item]:
        """The stage's items with effective cache keys; recorded in `lineage`."""
        gen = generations.get(stage.name, 0)
        of = lineage.of(ancestors(self.stages, stage.name))
        with (self.store.plan_config(self.cfg, stage) if self.store
              else contextlib.nullcontext(self.cfg)) as cfg:
            planned = stage.plan(cfg)
        items = [_effective(i, gen, of(i.key)) for i in planned]
        lineage.add(stage.name, items)
        return items

    def _run_stage(self, stage: Stage, items: list[Item],
                   executor: LocalExecutor | DaskExecutor, manifest: RunManifest,
                   failed_recordings: set[str], blocked: int = 0) -> StageSummary:
        """Execute and record one stage's items (those `runnable` left; `blocked` items were
        held back by a failed recording)."""
        t0 = time.perf_counter()
        summary = StageSummary(stage.name)
        summary.items = len(items)
        todo = [i for i in items
                if not manifest.is_done(stage.name, i.key.format(), i.cache_key)
                or self._damaged(stage, i)]
        summary.skipped = len(items) - len(todo)
        keys = {i.key: i for i in todo}
        if blocked and self.progress:
            self.console.print(Text.assemble((f"{stage.name:<8}", "bold"),
                                             f" not run: {blocked} item(s) of a failed "
                                             "recording (fix it and rerun)"))
        elif not todo and self.progress:
            self.console.print(Text.assemble((f"{stage.name:<8}", "bold"), " up to date"))
        try:
            self._execute(stage, todo, keys, executor, manifest, failed_recordings, summary)
        finally:
            if self.pending:
                self._write_manifest(manifest)
        summary.seconds = time.perf_counter() - t0
        return summary

    def _damaged(self, stage: Stage, item: Item) -> bool:
        """Whether a finished item's output tables are gone or unreadable (local outputs):
        logged, and the item is redone."""
        why = None if self.store else unreadable_output(stage, self.cfg, item)
        if why:
            log.warning("%s %s: its output is damaged (%s); redoing it", stage.name, item.key,
                        why)
        return why is not None

    def _execute(self, stage: Stage, todo: list[Item], keys: dict[ItemKey, Item],
                 executor: LocalExecutor | DaskExecutor, manifest: RunManifest,
                 failed_recordings: set[str], summary: StageSummary) -> None:
        """Run the items `todo` of `stage`, recording each finished one in `manifest`."""
        with self._bar(stage, len(todo)) as (bar, task):
            run = item_runner(stage, self.cfg)
            needs = stage.resources(self.cfg) if stage.resources is not None else None
            for key, outcome in executor.map(run, self.cfg, todo, self.cfg.dag.retries, needs):
                if isinstance(outcome, BaseException):
                    summary.failed[key.format()] = f"{type(outcome).__name__}: {outcome}"
                    summary.failed_recordings.add(_group(key))
                    log.error("%s %s failed: %s", stage.name, key, outcome)
                    bar.update(task, failed=len(summary.failed))  # never counted as done
                    self._failed_checks(manifest, key, outcome)
                    continue
                else:
                    summary.done += outcome.done
                    summary.rejected += outcome.rejected
                    for line in outcome.warnings:
                        log.warning("%s %s: %s", stage.name, key, line)
                    if failed_recordings and key.is_cross:
                        # built over the recordings that succeeded: redo it on the next run
                        log.warning("%s %s covers only the recordings that did not fail; it is"
                                    " recomputed on the next run", stage.name, key)
                    else:
                        if "checks" in outcome.detail and key.recording:
                            manifest.checks[key.recording] = list(outcome.detail["checks"])
                        manifest.mark_done(stage.name, key.format(), keys[key].cache_key)
                        self._record(manifest)
                bar.advance(task)

    def _failed_checks(self, manifest: RunManifest, key: ItemKey, err: BaseException) -> None:
        """A failed item's check rows, when its error carries them (`checks`: e.g. a failed
        geometry verdict), recorded in the manifest as a finished item's are; the item itself
        is not marked done."""
        rows = getattr(err, "checks", None)
        if isinstance(rows, list) and rows and key.recording:
            manifest.checks[key.recording] = list(rows)
            self._record(manifest)

    def _bar(self, stage: Stage, total: int) -> _Bar:
        """A progress bar for one stage (off when progress is off or nothing is to do)."""
        return _Bar(stage.name, total, self.progress and total > 0, self.console)


class _Bar:
    """Context manager around a progress bar with counts and rate (plain log lines, every
    tenth of the items or 10 s, when the console is not a terminal)."""

    def __init__(self, name: str, total: int, enabled: bool, console: Console) -> None:
        self.progress = make_progress(
            TextColumn("[bold]{task.description:<8}"), BarColumn(), MofNCompleteColumn(),
            TaskProgressColumn(show_speed=True), TimeElapsedColumn(),
            console=console, disable=not enabled, transient=False,
        )
        self.name, self.total = name, total

    def __enter__(self) -> tuple[Progress | LineProgress, TaskID]:
        self.progress.start()
        return self.progress, TaskID(self.progress.add_task(self.name, total=self.total))

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()
