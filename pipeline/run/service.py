"""The run policy: what happens around a run of the stage graph, decided once.

`m3gd run` (and `demo`, `ingest`, `select`), the benches and the tests that mean a run call
`run_stages`; the command only parses options and prints. The policy, in order:

1. refuse unknown stage names in `force` / `only` (exit code 2);
2. preflight, before any worker starts, so a refused run costs nothing: the output folder is
   reachable (`s3://`), every recording has a usable folder name and exists (on S3: can be
   listed), and a cache already there is of this format (exit code 2 with how to rebuild);
3. take the output lock (a stale lock of a dead run is taken over; `break_lock` takes over a
   lock of another host);
4. under the lock: `verify` first checks every cache chunk's CRC32C (items of corrupt chunks
   are forgotten so this run redoes them), then the executor the config asks for (or the
   in-process one for `local`) runs the stages, and is closed;
5. release the lock whatever happened; report the recordings the select stage left without a
   usable view.

Each refusal or stop is a `RunError` carrying one line and the exit code. What only higher
layers know (how an `s3://` recording is listed, how the cache is verified) comes in as
`RunHooks`; `dags.run` supplies the product's. Messages during the run (a lock taken over,
the Dask dashboard, the verify report) go to a `RunEvents` observer.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console

from pipeline.run.lock import LockHeld, OutputUnusable, acquire_output
from pipeline.run.stage import Stage
from schemas.cache_layout import check_root_attrs
from schemas.config import M3GDConfig
from schemas.errors import DataError, M3GDError
from schemas.names import name_problem
from schemas.stages import PostCheck, with_check
from schemas.versioning import UnknownSchemaVersion
from store.object_store import StorageError, is_url

log = logging.getLogger(__name__)

INTERRUPTED = "interrupted: finished items are kept; run the same command again to resume"
"""What a command says when the user interrupts a run (KeyboardInterrupt passes through
`run_stages`, the lock released: the caller decides how to stop)."""


class RunError(M3GDError):
    """A run refused before it started, or stopped: one line and the exit code to give."""

    def __init__(self, message: str, exit_code: int = 1) -> None:
        super().__init__(message)
        self.exit_code = exit_code


@dataclass(frozen=True)
class RunRequest:
    """What to run: `only` these stages (all when empty), `force` redoing a stage and all
    downstream of it; in-process when `local`; progress bars; the lock and verify options."""

    local: bool = True
    force: tuple[str, ...] = ()
    only: tuple[str, ...] = ()
    progress: bool = False
    break_lock: bool = False
    verify: bool = False


@dataclass(frozen=True)
class RunHooks:
    """The policy's pieces that live above `pipeline.run`.

    check_recording(location): raise StorageError when an `s3://` recording cannot be
    listed; verify(output_dir): check the cache's chunks and forget what is corrupt, under
    the held lock; its result goes to `RunEvents.verified` and `RunOutcome.verified`.
    """

    check_recording: Callable[[Path], Any] | None = None
    verify: Callable[[Path], Any] | None = None


class RunEvents:
    """Observer of a run's messages (the command prints them; the default ignores them)."""

    def took_over(self, holder: str) -> None:
        """A stale lock of a dead run (described by `holder`) was taken over."""

    def dashboard(self, link: str) -> None:
        """The Dask dashboard of the executor that runs the stages."""

    def verified(self, result: Any) -> None:
        """The verify hook's result, before any stage runs."""

    def lock_not_released(self, out: Path, err: Exception) -> None:
        """The output lock could not be released after the run (the store went away)."""


@dataclass
class RunOutcome:
    """Per-stage summaries (`pipeline.run.runner.StageSummary`), the verify result (None
    without verify) and one line per recording left without a usable view."""

    summaries: list[Any]
    verified: Any = None
    empty: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[tuple[str, str, str]]:
        """(stage, item key, error) of every failed item."""
        return [(s.name, k, e) for s in self.summaries for k, e in s.failed.items()]

    def failures(self, allow_empty: bool = False) -> int:
        """Failed items plus, unless `allow_empty`, recordings without a usable view."""
        return len(self.failed) + (0 if allow_empty else len(self.empty))


def run_stages(cfg: M3GDConfig, stages: Sequence[Stage], request: RunRequest | None = None,
               hooks: RunHooks | None = None, events: RunEvents | None = None,
               console: Console | None = None) -> RunOutcome:
    """Run `stages` for `cfg` under the run policy (module doc); RunError when refused or
    stopped. console: where progress bars go (the caller's, so its lines and bars share it)."""
    import pipeline.run.runner  # noqa: F401  (slow to import: before the lock, not under it)

    request, hooks, ev = request or RunRequest(), hooks or RunHooks(), events or RunEvents()
    preflight(cfg, stages, request, hooks)
    try:
        lock = acquire_output(cfg.output_dir, break_lock=request.break_lock)
    except (LockHeld, StorageError, OutputUnusable) as err:
        raise RunError(str(err)) from err
    try:
        check_store_tables(cfg, stages)
        verified = None
        if request.verify and hooks.verify is not None:
            verified = hooks.verify(cfg.output_dir)
            ev.verified(verified)
        summaries = _run_locked(cfg, stages, request, lock, ev, console)
    except StorageError as err:  # the store went away under the run (manifest, lock)
        raise RunError(f"the run stopped: {err}; finished items are kept: run the same "
                       "command again to resume once the store is reachable") from err
    except DataError as err:  # a plan that cannot read an output (items report their own)
        raise RunError(f"the run stopped: {err}") from err
    finally:
        release(lock, cfg.output_dir, ev)  # also when interrupted between acquiring and run
    return RunOutcome(summaries, verified, _empty_recordings(cfg, summaries))


def preflight(cfg: M3GDConfig, stages: Sequence[Stage], request: RunRequest,
              hooks: RunHooks | None = None) -> None:
    """Every check made before the lock is taken (steps 1 and 2 of the module doc)."""
    names = [s.name for s in stages]
    unknown = sorted((set(request.force) | set(request.only)) - set(names))
    if unknown:
        raise RunError(f"unknown stage {unknown[0]!r}; stages are {', '.join(names)}", 2)
    if request.verify:
        from pipeline.run.remote import LocalOnly, refuse_on_store

        try:
            refuse_on_store(cfg.output_dir, "verify")
        except LocalOnly as err:
            raise RunError(str(err), 2) from err
    check_output_reachable(cfg)
    check_recordings(cfg, hooks)
    check_cache_format(cfg)


def check_store_tables(cfg: M3GDConfig, stages: Sequence[Stage]) -> None:
    """For an `s3://` output (under its lock), what every local run does before planning:
    check the uploaded tables and metadata files against their uploaded checksum sidecars
    and forget, in the manifest on the store, what the run must redo (logged one line each;
    `pipeline.run.remote.StoreOutput.forget_damaged`)."""
    if not is_url(cfg.output_dir):
        return
    from pipeline.run.remote import StoreOutput
    from pipeline.run.stage import downstream_of

    store = StoreOutput(cfg.output_dir)
    manifest = store.read_manifest()
    if manifest is None:
        return
    lines = store.forget_damaged(manifest, lambda name: downstream_of(list(stages), name))
    for line in lines:
        log.warning("%s", line)
    if lines:
        store.write_manifest(manifest)


def release(lock: Any, out: Path, events: RunEvents | None = None) -> None:
    """Release the output lock; if that fails (the store went away), tell `events` instead
    of raising over the run's own outcome."""
    try:
        lock.release()
    except (StorageError, OSError) as err:
        (events or RunEvents()).lock_not_released(out, err)


def check_output_reachable(cfg: M3GDConfig) -> None:
    """RunError (exit 1) when an `s3://` output_dir cannot be reached."""
    from pipeline.run.remote import check_output

    try:
        check_output(cfg.output_dir)
    except StorageError as err:
        raise RunError(str(err)) from err


def check_recordings(cfg: M3GDConfig, hooks: RunHooks | None = None) -> None:
    """RunError (exit 2) naming the first recording whose name cannot be one or that is not
    a folder; exit 1 for a recording on `s3://` that cannot be listed (endpoint, bucket,
    credentials)."""
    for rec in cfg.ingest.recordings:
        problem = name_problem(Path(rec).name)
        if problem is not None:
            raise RunError(f"ingest.recordings: {rec}: its folder name {Path(rec).name!r} "
                           f"{problem}", 2)
        if is_url(rec):
            if hooks is not None and hooks.check_recording is not None:
                try:
                    hooks.check_recording(rec)
                except StorageError as err:
                    raise RunError(f"ingest.recordings: {err}") from err
        elif not Path(rec).is_dir():
            raise RunError(f"ingest.recordings: {rec} is not a folder (a mission folder of "
                           "bags)", 2)


def check_cache_format(cfg: M3GDConfig) -> None:
    """RunError (exit 2) with what to do when the output folder holds a cache of another
    format (a root whose `zarr.json` does not parse is left to the repair under the lock)."""
    from pipeline.run.checksums import metadata_problem
    from pipeline.run.remote import local_view
    from store.cache_io import node_attrs  # zarr: slow to import

    root = cfg.layout.cache
    try:
        with local_view(cfg.output_dir, ("cache.zarr/zarr.json",)) as out:
            if metadata_problem(out / "cache.zarr" / "zarr.json") is not None \
                    or not (out / "cache.zarr" / "zarr.json").exists():
                return  # a damaged root is named and written anew under the lock (checksums)
            check_root_attrs(node_attrs(out / "cache.zarr"), str(root))
    except (UnknownSchemaVersion, json.JSONDecodeError) as err:
        raise RunError(f"{err}; to rebuild it: rm -r {root} {cfg.layout.done} && m3gd run "
                       "--force ingest", 2) from err


def _run_locked(cfg: M3GDConfig, stages: Sequence[Stage], request: RunRequest, lock: Any,
                events: RunEvents, console: Console | None) -> list[Any]:
    """Start the executor and run the stages under the held `lock` (released by the caller)."""
    from pipeline.run.runner import Runner, make_executor

    if lock.took_over is not None:
        events.took_over(lock.took_over.describe())
    try:
        executor = make_executor(cfg, request.local)
    except OSError as err:
        raise RunError(f"cannot start or reach the Dask cluster: {err}") from err
    if executor.dashboard_link:
        events.dashboard(executor.dashboard_link)
    try:
        summaries: list[Any] = Runner(cfg, list(stages), progress=request.progress,
                                      console=console).run(
            executor, force=list(request.force), only=list(request.only), locked=True)
    finally:
        executor.close()
    return summaries


def _empty_recordings(cfg: M3GDConfig, summaries: list[Any]) -> list[str]:
    """Lines for the recordings this run left without a usable view, when it ran a stage
    the stage table checks for them (`schemas.stages.PostCheck.EMPTY_RECORDINGS`)."""
    checked = with_check(PostCheck.EMPTY_RECORDINGS)
    if not any(s.name in checked for s in summaries):
        return []
    from pipeline.run.outcome import empty_recordings
    from pipeline.run.remote import local_view
    from schemas.missions import recording_names

    with local_view(cfg.output_dir, ("index",)) as out:
        return empty_recordings(out, recording_names(cfg))
