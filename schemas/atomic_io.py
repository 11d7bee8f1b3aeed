"""Atomic small-file writes: a reader sees the old file or the new one, never a partial one."""

from __future__ import annotations

import os
from pathlib import Path


def write_text_atomic(path: Path, text: str) -> Path:
    """Write `text` to a process-private temporary beside `path`, then rename it over `path`.

    Creates the parent folder. A kill mid-write leaves at most a stray `.tmp` file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path
