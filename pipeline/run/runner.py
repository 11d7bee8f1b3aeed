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
import platform
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)

from pipeline.run.executors import DaskExecutor, LocalExecutor
from pipeline.run.lock import OutputLock
from pipeline.run.stage import Item, Stage, downstream_of, topological
from schemas.config import M3GDConfig, config_hash
from schemas.manifest import RunManifest, read_manifest, write_manifest

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


def _effective(item: Item, generation: int) -> Item:
    """The item with its cache key salted by the stage generation (bumped by --force)."""
    if generation == 0:
        return item
    salted = hashlib.sha256(f"{item.cache_key}:{generation}".encode()).hexdigest()
    return Item(item.key, salted)


GLOBAL_PREFIX = "_"
"""Item keys of cross-recording items (latent normalization, clip index) start with this."""


def _recording_of(key: str) -> str:
    """Recording name of an item key ('<recording>' or '<recording>/...')."""
    return key.split("/", 1)[0]


def make_executor(cfg: M3GDConfig, local: bool) -> LocalExecutor | DaskExecutor:
    """The executor the config (or --local) asks for."""
    if local or (cfg.dag.executor == "local" and not cfg.dag.scheduler):
        return LocalExecutor()
    return DaskExecutor(cfg.dag.workers, cfg.dag.scheduler, cfg.dag.dashboard)


class Runner:
    """Runs a list of stages for one configuration and output directory."""

    def __init__(self, cfg: M3GDConfig, stages: list[Stage], progress: bool = True) -> None:
        self.cfg = cfg
        self.stages = topological(stages)
        self.out: Path = cfg.output_dir
        self.progress = progress

    def run(self, executor: LocalExecutor | DaskExecutor, force: list[str] | None = None,
            only: list[str] | None = None, locked: bool = False) -> list[StageSummary]:
        """Run every stage (or `only` those) under the output lock; return summaries.

        locked: the caller already holds the output lock (`OutputLock`).
        """
        with contextlib.nullcontext() if locked else OutputLock(self.out):
            manifest = read_manifest(self.out) or new_manifest(self.cfg)
            manifest.config_hash = config_hash(self.cfg)
            generations = self._bump(manifest, force or [])
            write_manifest(manifest, self.out)
            failed_recordings: set[str] = set()
            summaries = []
            for stage in self.stages:
                if only and stage.name not in only:
                    continue
                summary = self._run_stage(stage, executor, manifest, generations, failed_recordings)
                summaries.append(summary)
                failed_recordings.update(_recording_of(k) for k in summary.failed)
            return summaries

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

    def _run_stage(self, stage: Stage, executor: LocalExecutor | DaskExecutor,
                   manifest: RunManifest, generations: dict[str, int],
                   failed_recordings: set[str]) -> StageSummary:
        """Plan, filter, execute and record one stage."""
        t0 = time.perf_counter()
        summary = StageSummary(stage.name)
        gen = generations.get(stage.name, 0)
        items = [_effective(i, gen) for i in stage.plan(self.cfg)]
        items = [i for i in items if _recording_of(i.key) not in failed_recordings]
        summary.items = len(items)
        todo = [i for i in items if not manifest.is_done(stage.name, i.key, i.cache_key)]
        summary.skipped = len(items) - len(todo)
        keys = {i.key: i for i in todo}
        with self._bar(stage, len(todo)) as (bar, task):
            for key, outcome in executor.map(stage.run, self.cfg, todo, self.cfg.dag.retries):
                if isinstance(outcome, BaseException):
                    summary.failed[key] = f"{type(outcome).__name__}: {outcome}"
                    log.error("%s %s failed: %s", stage.name, key, outcome)
                else:
                    summary.done += outcome.done
                    summary.rejected += outcome.rejected
                    if failed_recordings and key.startswith(GLOBAL_PREFIX):
                        # built over the recordings that succeeded: redo it on the next run
                        log.warning("%s %s covers only the recordings that did not fail; it is"
                                    " recomputed on the next run", stage.name, key)
                    else:
                        manifest.mark_done(stage.name, key, keys[key].cache_key)
                        write_manifest(manifest, self.out)
                bar.advance(task)
        summary.seconds = time.perf_counter() - t0
        return summary

    def _bar(self, stage: Stage, total: int) -> _Bar:
        """A progress bar for one stage (off when progress is off or nothing is to do)."""
        if total == 0 and self.progress:
            from pipeline.cli_common import console

            console.print(f"[bold]{stage.name:<8}[/bold] up to date")
        return _Bar(stage.name, total, self.progress and total > 0)


class _Bar:
    """Context manager around a rich progress bar with counts and rate."""

    def __init__(self, name: str, total: int, enabled: bool) -> None:
        from pipeline.cli_common import console

        self.progress = Progress(
            TextColumn("[bold]{task.description:<8}"), BarColumn(), MofNCompleteColumn(),
            TaskProgressColumn(show_speed=True), TimeElapsedColumn(),
            console=console, disable=not enabled, transient=False,
        )
        self.name, self.total = name, total

    def __enter__(self) -> tuple[Progress, int]:
        self.progress.start()
        return self.progress, self.progress.add_task(self.name, total=self.total)

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()
