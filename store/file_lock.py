"""File locks of this host: `flock` on a lock file, the one primitive m3gd's locks build on.

`flocked` holds a blocking lock (exclusive or shared) for a with-block: the cache store's
array replacement and the S3 mirror's eviction use it. `try_flock` takes an exclusive lock
without waiting and `same_file` checks that a locked file is still the one at its path: the
run's output lock (`pipeline.run.lock`) is built on those two. The kernel releases a `flock`
when its holder exits or dies, so a killed process never leaves a file locked.
"""

from __future__ import annotations

import errno
import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

EXCLUSIVE = fcntl.LOCK_EX
SHARED = fcntl.LOCK_SH


@contextmanager
def flocked(path: Path, mode: int = EXCLUSIVE) -> Iterator[None]:
    """Hold a `flock` of `mode` (EXCLUSIVE or SHARED) on the file `path` (created if
    missing; its folder must exist) for the with-block, waiting until it is free."""
    with path.open("a") as handle:
        fcntl.flock(handle, mode)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def try_flock(fd: int) -> bool:
    """Take an exclusive flock on `fd` without waiting; False when another process holds it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as err:
        if err.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


def same_file(fd: int, path: Path) -> bool:
    """Whether `fd` is still the file at `path` (not unlinked or replaced meanwhile)."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return False
    fst = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (fst.st_dev, fst.st_ino)
