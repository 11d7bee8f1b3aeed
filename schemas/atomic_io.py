"""Atomic file writes: a reader sees the old file or the new one, never a partial one."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def write_atomic(path: Path, write: Callable[[BinaryIO], None]) -> Path:
    """Let `write` fill a process-private temporary beside `path`, then rename it over `path`.

    Creates the parent folder. A kill mid-write leaves at most a stray `.tmp` file, which
    the next write of the same path removes.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    for stale in path.parent.glob(f".{path.name}.*.tmp"):  # left by a killed writer
        stale.unlink(missing_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            write(f)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise with_path(err, path) from err
    os.replace(tmp, path)
    return path


def with_path(err: OSError, path: Path) -> OSError:
    """`err` naming `path` when it names no file (a full disk raises `[Errno 28] No space left
    on device` from a write, without the file's name); else `err` itself."""
    if err.filename is not None or err.errno is None:
        return err
    return type(err)(err.errno, err.strerror, str(path))


def write_text_atomic(path: Path, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically (see `write_atomic`)."""
    data = text.encode()

    def write(f: BinaryIO) -> None:
        f.write(data)

    return write_atomic(path, write)
