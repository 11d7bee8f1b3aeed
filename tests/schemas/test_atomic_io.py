"""Atomic writes: errors name the file."""

from __future__ import annotations

import errno
from pathlib import Path
from typing import BinaryIO

import pytest

from schemas.atomic_io import write_atomic


def test_a_full_disk_names_the_file(tmp_path: Path) -> None:
    """Was: `[Errno 28] No space left on device` with no path; the temporary is removed."""
    def full(f: BinaryIO) -> None:
        f.write(b"x")
        raise OSError(errno.ENOSPC, "No space left on device")

    target = tmp_path / "a" / "shard"
    with pytest.raises(OSError, match=rf"No space left on device: '{target}'") as info:
        write_atomic(target, full)
    assert info.value.errno == errno.ENOSPC and not list(target.parent.iterdir())
