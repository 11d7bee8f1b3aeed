"""An output-directory lock: one run writes an output at a time; a dead run's lock is taken over.

The lock is an OS lock (`flock`, exclusive, non-blocking) on the file `.m3gd.lock`, held for the
whole run. The kernel releases it when its holder exits or dies, so two processes can never both
hold it and taking over a dead run's lock has no check-then-replace race. After locking, the
holder checks that the file it locked is still the one at the path (a releasing run unlinks it),
then writes its name (host, pid, start time) into it for the messages of others.

A lock file naming another host whose lock is not held here is refused: on a shared file system
flock may not reach across hosts, so m3gd cannot tell whether that run is alive. The message says
what to do: `m3gd unlock <out>` (or `run --break-lock`) once that run is known to be gone.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from types import TracebackType

from schemas.errors import M3GDError

LOCK_NAME = ".m3gd.lock"


class LockHeld(M3GDError, RuntimeError):
    """Another run holds the output lock (or may: a lock from another host)."""


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


def _read(path: Path) -> Holder | None:
    """The holder recorded in a lock file, or None when empty or unreadable."""
    try:
        return Holder(**json.loads(path.read_text()))
    except (OSError, ValueError, TypeError):
        return None


def _try_flock(fd: int) -> bool:
    """Take an exclusive flock on `fd` without waiting; False when another process holds it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as err:
        if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


def _same_file(fd: int, path: Path) -> bool:
    """Whether `fd` is still the file at `path` (not unlinked or replaced meanwhile)."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return False
    fst = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (fst.st_dev, fst.st_ino)


def running_holder(out_dir: Path) -> Holder | None:
    """The run writing `out_dir` right now, if any: its lock file exists (a run removes it
    when it ends) and names a live process of this host, or another host (which m3gd cannot
    check from here: reported as possibly running). Takes no lock."""
    holder = _read(out_dir / LOCK_NAME)
    if holder is None:
        return None
    if holder.host != socket.gethostname():
        return holder
    try:
        os.kill(holder.pid, 0)
    except ProcessLookupError:
        return None  # a killed run's file: nobody writes
    except PermissionError:
        pass  # alive, another user's
    return holder


class OutputLock:
    """Context manager holding the lock of one output directory."""

    def __init__(self, out_dir: Path, break_lock: bool = False) -> None:
        """`break_lock`: take over a lock naming another host (the user says it is gone)."""
        self.path = out_dir / LOCK_NAME
        self.me = Holder(socket.gethostname(), os.getpid(), time.time())
        self.break_lock = break_lock
        self.took_over: Holder | None = None
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock; LockHeld naming the holder when a live run (or another host) has it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            if not _try_flock(fd):
                os.close(fd)
                holder = _read(self.path)
                who = holder.describe() if holder else "holder not yet recorded"
                raise LockHeld(f"{self.path.parent} is locked by another m3gd run ({who})")
            if _same_file(fd, self.path):
                break
            os.close(fd)  # a releasing run unlinked it between our open and our flock: again
        holder = _read(self.path)
        if holder is not None and holder.host != self.me.host and not self.break_lock:
            os.close(fd)
            raise LockHeld(
                f"{self.path.parent} is locked by an m3gd run on another host "
                f"({holder.describe()}); m3gd cannot tell from here whether it is still running. "
                f"If it is not, run `m3gd unlock {self.path.parent}` (or `m3gd run --break-lock`)"
            )
        self.took_over = holder
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(asdict(self.me)).encode(), 0)
        os.fsync(fd)
        self._fd = fd

    def release(self) -> None:
        """Unlink the lock file and drop the OS lock, if this process holds it."""
        if self._fd is None:
            return
        if _same_file(self._fd, self.path):
            self.path.unlink(missing_ok=True)
        os.close(self._fd)  # releases the flock
        self._fd = None

    def __enter__(self) -> OutputLock:
        self.acquire()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.release()
