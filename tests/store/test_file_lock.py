"""`store.file_lock`: a held exclusive flock refuses a non-blocking taker, a shared one admits
shared holders, and the with-block's end (also on an exception) releases it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from store.file_lock import SHARED, flocked, same_file, try_flock


def _try(path: Path) -> bool:
    """Whether another open file description can take the exclusive lock now (then drops it)."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT)
    try:
        return try_flock(fd)
    finally:
        os.close(fd)


def test_exclusive_refuses_then_releases_on_exception(tmp_path: Path) -> None:
    path = tmp_path / ".lock"
    with pytest.raises(KeyError), flocked(path):
        assert not _try(path)
        raise KeyError("failed under the lock")
    assert _try(path)


def test_shared_admits_shared_not_exclusive(tmp_path: Path) -> None:
    path = tmp_path / ".lock"
    with flocked(path, SHARED), flocked(path, SHARED):
        assert not _try(path)
    assert _try(path)


def test_same_file_sees_unlink_and_replace(tmp_path: Path) -> None:
    path = tmp_path / ".lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT)
    try:
        assert same_file(fd, path)
        path.unlink()
        assert not same_file(fd, path)
        path.write_text("")
        assert not same_file(fd, path)
    finally:
        os.close(fd)
