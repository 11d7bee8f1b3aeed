"""The output lock of a run: one run writes an output at a time; a dead run's lock is taken over.

One API for every output: `acquire_output` / `held_output` (what a run takes), `unlock`
(`m3gd unlock`), `running_holder` (the report's "a run is writing this"), `LockHeld` naming
the holder (host, pid, start time) when another run has it.

A local folder: an OS lock (`flock`, exclusive, non-blocking: `store.file_lock`) on the file
`.m3gd.lock`, held for the whole run. The kernel releases it when its holder exits or dies, so
two processes can never both hold it and taking over a dead run's lock has no
check-then-replace race. After locking, the holder checks that the file it locked is still the
one at the path (a releasing run unlinks it), then writes its name into it for the messages
of others.

An `s3://` prefix: one object `<prefix>/.m3gd.lock` created by a conditional PUT
(`If-None-Match: *`): the store creates it only if no object has that key, atomically, so of
two runs starting together exactly one gets it (AWS S3 has honoured the header since August
2024; the moto server the tests start does, tested; a store that ignores it would let a
second run overwrite the lock, which `acquire` detects by reading the lock back and refusing
when it names another run, a check that narrows but cannot close the race). `release`
deletes the object only if it is still the one this run wrote (`If-Match` on its ETag).
Nothing releases the object when its holder dies: a lock naming this host and a process that
no longer exists is taken over. Connection settings come from the environment.

Either way a lock naming another host is refused (flock may not reach across hosts on a
shared file system, and an object never does: m3gd cannot tell whether that run is alive),
with what to do: `m3gd unlock <out>` (or `run --break-lock`) once that run is known gone.
"""

from __future__ import annotations

import json
import os
import socket
import time
from abc import ABC, abstractmethod
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from schemas.errors import M3GDError
from store.file_lock import same_file, try_flock
from store.object_store import StorageError, is_url, parse_url, reason, where

LOCK_NAME = ".m3gd.lock"
ATTEMPTS = 5  # conditional PUTs of an object lock before giving up (others keep taking it)


class LockHeld(M3GDError, RuntimeError):
    """Another run holds the output lock (or may: a lock from another host)."""


class OutputUnusable(M3GDError, OSError):
    """The output folder cannot hold a lock (permissions, not a folder, a full disk)."""


@dataclass(frozen=True)
class Holder:
    """Who holds a lock."""

    host: str
    pid: int
    started_unix_s: float

    def describe(self) -> str:
        """Human-readable holder: host, pid, start time."""
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started_unix_s))
        return f"host {self.host}, pid {self.pid}, started {when}"


def _parse(data: str | bytes) -> Holder | None:
    """The holder recorded in a lock's bytes, or None when empty or unparsable."""
    try:
        return Holder(**json.loads(data))
    except (ValueError, TypeError):
        return None


def _read(path: Path) -> Holder | None:
    """The holder recorded in a lock file, or None when absent, empty or unreadable."""
    try:
        return _parse(path.read_text())
    except OSError:
        return None


def _alive_here(holder: Holder) -> bool:
    """Whether `holder` names a process of this host that still exists."""
    if holder.host != socket.gethostname():
        return False
    try:
        os.kill(holder.pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # alive, another user's
    return True


def _other_host(where_: object, holder: Holder) -> LockHeld:
    """The refusal of a lock naming another host, with what to do."""
    return LockHeld(
        f"{where_} is locked by an m3gd run on another host ({holder.describe()}); m3gd cannot "
        f"tell from here whether it is still running. If it is not, run `m3gd unlock {where_}` "
        "(or `m3gd run --break-lock`)")


def running_holder(out_dir: Path) -> Holder | None:
    """The run writing the local folder `out_dir` right now, if any: its lock file exists (a
    run removes it when it ends) and names a live process of this host, or another host
    (which m3gd cannot check from here: reported as possibly running). Takes no lock."""
    holder = _read(out_dir / LOCK_NAME)
    if holder is None or (holder.host == socket.gethostname() and not _alive_here(holder)):
        return None  # none, or a killed run's file: nobody writes
    return holder


class _Lock(ABC):
    """What both locks share: the holder this run writes, `took_over`, the with-block."""

    def __init__(self, break_lock: bool) -> None:
        """`break_lock`: take over a lock naming another host (the user says it is gone)."""
        self.me = Holder(socket.gethostname(), os.getpid(), time.time())
        self.break_lock = break_lock
        self.took_over: Holder | None = None

    @abstractmethod
    def acquire(self) -> None:
        """Take the lock; LockHeld naming the holder when a live run (or another host) has it."""

    @abstractmethod
    def release(self) -> None:
        """Give the lock up if this run holds it (the with-block's end, also on an exception)."""

    def __enter__(self) -> Self:
        self.acquire()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()


class OutputLock(_Lock):
    """The lock of one local output folder: a flocked file."""

    def __init__(self, out_dir: Path, break_lock: bool = False) -> None:
        super().__init__(break_lock)
        self.path = out_dir / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock; LockHeld naming the holder when a live run (or another host) has it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            if not try_flock(fd):
                os.close(fd)
                holder = _read(self.path)
                who = holder.describe() if holder else "holder not yet recorded"
                raise LockHeld(f"{self.path.parent} is locked by another m3gd run ({who})")
            if same_file(fd, self.path):
                break
            os.close(fd)  # a releasing run unlinked it between our open and our flock: again
        holder = _read(self.path)
        if holder is not None and holder.host != self.me.host and not self.break_lock:
            os.close(fd)
            raise _other_host(self.path.parent, holder)
        self.took_over = holder
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(asdict(self.me)).encode(), 0)
        os.fsync(fd)
        self._fd = fd

    def release(self) -> None:
        """Unlink the lock file and drop the OS lock, if this process holds it."""
        if self._fd is None:
            return
        if same_file(self._fd, self.path):
            self.path.unlink(missing_ok=True)
        os.close(self._fd)  # releases the flock
        self._fd = None


def _code(err: Exception) -> str:
    """The S3 error code of a botocore ClientError ('' for other errors)."""
    response = getattr(err, "response", None)
    return str(response.get("Error", {}).get("Code", "")) if isinstance(response, dict) else ""


class StoreLock(_Lock):
    """The lock of one output on object storage: an object created by a conditional PUT."""

    def __init__(self, location: Path | str, break_lock: bool = False) -> None:
        super().__init__(break_lock)
        self.url = parse_url(location)
        self.key = "/".join(p for p in (self.url.prefix, LOCK_NAME) if p)
        self.where = where(self.url.url(LOCK_NAME))
        self._etag: str | None = None
        from pipeline.run.store_sync import client  # pyarrow's S3: only for an s3:// output

        self._s3 = client()

    def _call(self, name: str, **kw: Any) -> Any:
        """One S3 call on the lock object; StorageError (one line) for the store's errors
        except the ones the caller handles (412, 404, 409), which are re-raised."""
        from botocore.exceptions import BotoCoreError, ClientError

        try:
            return getattr(self._s3, name)(Bucket=self.url.bucket, Key=self.key, **kw)
        except ClientError as err:
            if _code(err) in ("PreconditionFailed", "NoSuchKey", "404",
                              "ConditionalRequestConflict"):
                raise
            if _code(err) == "NoSuchBucket":
                raise StorageError(f"{self.where}: no such bucket {self.url.bucket!r}") from err
            raise StorageError(f"{self.where}: {reason(err)}") from err
        except BotoCoreError as err:
            raise StorageError(f"{self.where}: {reason(err)}") from err

    def read(self) -> tuple[Holder | None, str | None]:
        """(holder, ETag) of the lock object; (None, None) when there is none."""
        from botocore.exceptions import ClientError

        try:
            got = self._call("get_object")
        except ClientError:
            return None, None
        return _parse(got["Body"].read()), str(got["ETag"])

    def _create(self) -> bool:
        """PUT the lock object if none exists; True when this run created it."""
        from botocore.exceptions import ClientError

        try:
            put = self._call("put_object", Body=json.dumps(asdict(self.me)).encode(),
                             IfNoneMatch="*", ContentType="application/json")
        except ClientError:  # 412: it exists; 409: a concurrent conditional write won
            return False
        self._etag = str(put["ETag"])
        return True

    def _delete(self, etag: str) -> bool:
        """Delete the lock object if its ETag is still `etag`; True when deleted (or gone)."""
        from botocore.exceptions import ClientError

        try:
            self._call("delete_object", IfMatch=etag)
        except ClientError as err:
            return _code(err) in ("NoSuchKey", "404")
        return True

    def acquire(self) -> None:
        """Take the lock; LockHeld naming the holder when a live run (or another host) has it."""
        for _ in range(ATTEMPTS):
            if self._create():
                holder, _ = self.read()
                if holder == self.me:
                    return
                raise LockHeld(f"{self.url} is locked by another m3gd run "
                               f"({holder.describe() if holder else 'holder unreadable'}): "
                               "the store ignored the conditional write")
            holder, etag = self.read()
            if etag is None:
                continue  # released meanwhile: try again
            if holder is not None and _alive_here(holder):
                raise LockHeld(f"{self.url} is locked by another m3gd run ({holder.describe()})")
            if holder is not None and holder.host != self.me.host and not self.break_lock:
                raise _other_host(self.url, holder)
            if self._delete(etag):  # a dead run of this host, or broken on purpose
                self.took_over = holder
        raise LockHeld(f"{self.url}: could not take the lock in {ATTEMPTS} attempts "
                       "(other runs keep taking it)")

    def release(self) -> None:
        """Delete the lock object if this run still holds it."""
        if self._etag is not None:
            self._delete(self._etag)
            self._etag = None


def output_lock(out_dir: Path, break_lock: bool = False) -> OutputLock | StoreLock:
    """The lock of `out_dir` (not yet taken): a `StoreLock` for an `s3://` output, else an
    `OutputLock`; both acquire, release, name `took_over` and work as context managers."""
    if is_url(out_dir):
        return StoreLock(out_dir, break_lock=break_lock)
    return OutputLock(out_dir, break_lock=break_lock)


def unlock(out_dir: Path) -> Holder | None:
    """Remove the lock of `out_dir` unless a live run on this host holds it; the old holder
    (None when there was no lock). LockHeld when a live process holds it. A lock naming
    another host is removed: the caller is the one who knows that run is gone."""
    if is_url(out_dir):
        store = StoreLock(out_dir, break_lock=True)
        holder, etag = store.read()
        if etag is None:
            return None
        if holder is not None and _alive_here(holder):
            raise LockHeld(f"{store.url} is locked by a running m3gd run ({holder.describe()})")
        store._delete(etag)
        return holder
    lock = OutputLock(out_dir, break_lock=True)
    if not lock.path.exists():
        return None
    lock.acquire()
    old = lock.took_over
    lock.release()
    return old


def acquire_output(out_dir: Path, break_lock: bool = False) -> OutputLock | StoreLock:
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
def held_output(out_dir: Path, break_lock: bool = False) -> Iterator[OutputLock | StoreLock]:
    """`acquire_output` for the duration of a with-block; released at its end (also when
    the block raises)."""
    lock = acquire_output(out_dir, break_lock)
    try:
        yield lock
    finally:
        lock.release()
