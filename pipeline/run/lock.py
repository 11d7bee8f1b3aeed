"""An output-directory lock: one run writes an output at a time; stale locks are taken over.

The lock is a JSON file created with O_EXCL naming its holder (host, pid, start
time). A lock whose holder is on this host and no longer alive is stale and is
replaced atomically; a live holder gives a clear error naming it.
"""

from __future__ import annotations

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
    """Another live run holds the output lock."""


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


def _alive(pid: int) -> bool:
    """True when a process with `pid` exists on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _read(path: Path) -> Holder | None:
    """The holder recorded in a lock file, or None when unreadable."""
    try:
        return Holder(**json.loads(path.read_text()))
    except (OSError, ValueError, TypeError):
        return None


class OutputLock:
    """Context manager holding the lock of one output directory."""

    def __init__(self, out_dir: Path) -> None:
        self.path = out_dir / LOCK_NAME
        self.me = Holder(socket.gethostname(), os.getpid(), time.time())
        self.took_over: Holder | None = None

    def _create(self) -> bool:
        """Try to create the lock file exclusively."""
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        with os.fdopen(fd, "w") as f:
            json.dump(asdict(self.me), f)
        return True

    def acquire(self) -> None:
        """Take the lock, replacing a stale one; raise LockHeld naming a live holder."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self._create():
            return
        holder = _read(self.path)
        stale = holder is None or (holder.host == self.me.host and not _alive(holder.pid))
        if not stale:
            assert holder is not None
            raise LockHeld(
                f"{self.path.parent} is locked by another m3gd run ({holder.describe()})"
            )
        tmp = self.path.with_name(f"{LOCK_NAME}.{self.me.pid}")
        tmp.write_text(json.dumps(asdict(self.me)))
        os.replace(tmp, self.path)
        self.took_over = holder

    def release(self) -> None:
        """Remove the lock if this process still holds it."""
        holder = _read(self.path)
        if holder is not None and holder.pid == self.me.pid and holder.host == self.me.host:
            self.path.unlink(missing_ok=True)

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
