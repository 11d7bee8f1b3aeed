"""Positioned reads that work on every filesystem: `preadv` with `RWF_NOWAIT` (ask the page
cache alone) where the filesystem supports it, a plain `preadv` where it does not (tmpfs,
network, FUSE and object-store mounts answer EOPNOTSUPP, EINVAL or ENOSYS), one `pread` per
buffer where `preadv` itself is refused or missing. What a filesystem supports is learned
from its first refusal and kept in its `FsReads` (one per `st_dev` in a reader), so the
decision is made once per filesystem, never per read."""

from __future__ import annotations

import errno
import os
from contextlib import suppress
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

UNSUPPORTED = frozenset({errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL, errno.ENOSYS})
"""What a filesystem (or kernel) answers to a read flag or call it does not implement."""


@dataclass
class FsReads:
    """What one filesystem (st_dev) supports, learned from its first refusal: `nowait`
    (preadv with RWF_NOWAIT) and `vectored` (preadv at all). Shared by its open files."""

    nowait: bool = field(default_factory=lambda: hasattr(os, "preadv")
                         and hasattr(os, "RWF_NOWAIT"))  # fmt: skip
    vectored: bool = field(default_factory=lambda: hasattr(os, "preadv"))


def refused(err: OSError, fs: FsReads, what: Literal["nowait", "vectored"]) -> int:
    """0 after turning `what` off for the filesystem `fs` (preadv's flag RWF_NOWAIT, or
    preadv itself: then the flag too) when `err` says it is not supported; else raise `err`."""
    if err.errno not in UNSUPPORTED:
        raise err
    fs.nowait = False
    if what == "vectored":
        fs.vectored = False
    return 0


def will_need(fd: int, offset: int, nbytes: int) -> None:
    """Advise the kernel to read [offset, offset + nbytes) of `fd` soon; a no-op where the
    platform or filesystem has no such advice (it is only a hint)."""
    if hasattr(os, "posix_fadvise"):
        with suppress(OSError):
            os.posix_fadvise(fd, offset, nbytes, os.POSIX_FADV_WILLNEED)


def read_each(fd: int, buffers: list[NDArray[np.uint8]], offset: int) -> int:
    """Bytes read into `buffers` from `offset` with one pread per buffer (no preadv)."""
    done = 0
    for b in buffers:
        data = os.pread(fd, b.size, offset + done)
        b[:len(data)] = np.frombuffer(data, np.uint8)
        done += len(data)
        if len(data) < b.size:
            break
    return done


def skip(buffers: list[NDArray[np.uint8]], nbytes: int) -> list[NDArray[np.uint8]]:
    """`buffers` without their first `nbytes` bytes (those already read)."""
    out = []
    for b in buffers:
        if nbytes >= b.size:
            nbytes -= b.size
            continue
        out.append(b[nbytes:])
        nbytes = 0
    return out
