"""The output lock of a run, whatever the output is: a local folder (`pipeline.run.lock`) or an
`s3://` prefix (`pipeline.run.store_lock`). The one way a run (CLI or `Runner.run`) takes it."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from pipeline.run.lock import Holder, LockHeld, OutputLock
from pipeline.run.store_lock import StoreLock, unlock_store
from schemas.errors import M3GDError
from store.object_store import StorageError, is_url


class OutputUnusable(M3GDError, OSError):
    """The output folder cannot hold a lock (permissions, not a folder, a full disk)."""


def output_lock(out_dir: Path, break_lock: bool = False) -> Any:
    """The lock of `out_dir`: an `OutputLock`, or for an `s3://` output a
    `pipeline.run.store_lock.StoreLock` (same interface: acquire, release, took_over)."""
    if is_url(out_dir):
        return StoreLock(out_dir, break_lock=break_lock)
    return OutputLock(out_dir, break_lock=break_lock)


def unlock(out_dir: Path) -> Holder | None:
    """Remove the lock of `out_dir` unless a live run on this host holds it; the old holder.

    LockHeld when a live process holds the OS lock. A lock naming another host is removed: the
    caller is the one who knows that run is gone. An `s3://` output: its lock object
    (`pipeline.run.store_lock.unlock_store`).
    """
    if is_url(out_dir):
        return unlock_store(out_dir)
    lock = OutputLock(out_dir, break_lock=True)
    if not lock.path.exists():
        return None
    lock.acquire()
    old = lock.took_over
    lock.release()
    return old


def acquire_output(out_dir: Path, break_lock: bool = False) -> Any:
    """The output lock of `out_dir`, acquired. Raises LockHeld (another live run holds it),
    StorageError (object storage refused), or OutputUnusable (one line naming the folder)."""
    lock = output_lock(out_dir, break_lock=break_lock)
    try:
        lock.acquire()
    except (LockHeld, StorageError):
        raise
    except OSError as err:
        raise OutputUnusable(f"{out_dir}: cannot be used as the output folder: "
                             f"{err.strerror or err} ({err.filename or out_dir})") from err
    return lock


@contextmanager
def held_output(out_dir: Path, break_lock: bool = False) -> Iterator[Any]:
    """`acquire_output` for the duration of a with-block; released at its end."""
    lock = acquire_output(out_dir, break_lock)
    try:
        yield lock
    finally:
        lock.release()
