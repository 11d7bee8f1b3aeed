"""The shard reader on filesystems without RWF_NOWAIT or preadv: tmpfs (a real one), a
read-only file, and refusals (EOPNOTSUPP, EINVAL, ENOSYS, a missing os.preadv) simulated;
what a filesystem supports is learned once, and real I/O errors still surface."""

from __future__ import annotations

import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from store.cache_io import read_clip
from store.pread_io import FsReads, read_each, skip
from store.shard_reader import ShardReader
from tests.store.test_shard_reader import _store, _views

NAMES = ["latents_l0", "g", "h_rows"]
FRAMES = [[0, 1, 2, 3], [10, 3, 9, 0], [5, 8, 10], [7]]


def _tmpfs_dirs() -> list[str]:
    """Mount points of writable tmpfs filesystems (/proc/mounts), /dev/shm first."""
    try:
        lines = Path("/proc/mounts").read_text().splitlines()
    except OSError:
        return []
    mounts = [p[1] for p in (line.split() for line in lines)
              if len(p) > 3 and p[2] == "tmpfs" and "rw" in p[3].split(",")]
    return sorted((m for m in mounts if os.access(m, os.W_OK)), key=lambda m: m != "/dev/shm")


@pytest.fixture
def tmpfs_path() -> Iterator[Path]:
    """A fresh directory on a tmpfs, removed afterwards."""
    dirs = _tmpfs_dirs()
    if not dirs:
        pytest.skip("no writable tmpfs mounted on this machine (/proc/mounts)")
    path = Path(tempfile.mkdtemp(prefix="m3gd-tmpfs-", dir=dirs[0]))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def _check_values(group: Path, data: dict[str, np.ndarray], reader: ShardReader) -> None:
    """Every clip of FRAMES read by `reader` equals what was written."""
    for frames in FRAMES:
        got = read_clip(group, NAMES, frames, reader)
        np.testing.assert_array_equal(got["latents_l0"], data["latents_l0"][frames])
        np.testing.assert_array_equal(got["g"], data["g"][frames])
        dense = np.moveaxis(data["h"][frames], 1, -1)
        np.testing.assert_array_equal(got["h_rows"], dense[data["g"][frames][:, 0] > 0.5])


class _CountingPreadv:
    """os.preadv that counts its calls with and without flags, refusing some with `refuse`."""

    def __init__(self, refuse: dict[str, int]) -> None:
        self.real = os.preadv
        self.refuse = refuse
        self.calls = {"nowait": 0, "plain": 0}

    def __call__(self, fd: int, buffers: Any, offset: int, flags: int = 0) -> int:
        kind = "nowait" if flags else "plain"
        self.calls[kind] += 1
        if kind in self.refuse:
            raise OSError(self.refuse[kind], os.strerror(self.refuse[kind]))
        return self.real(fd, buffers, offset, flags)


def test_a_cache_on_tmpfs_reads_and_learns_once(tmpfs_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    data = _views(3)
    group = _store(tmpfs_path, data, [0, 1, 2])
    counting = _CountingPreadv({})
    monkeypatch.setattr(os, "preadv", counting)
    reader = ShardReader()
    _check_values(group, data, reader)
    (fs,) = reader._fs.values()  # one filesystem
    if fs.nowait:  # a kernel whose tmpfs takes the flag: the fast path, nothing to learn
        return
    assert counting.calls["nowait"] == 1  # refused once, never asked again on this filesystem
    assert reader.misses == 0  # a refusal is no page-cache miss
    assert counting.calls["plain"] > 0 and fs.vectored


@pytest.mark.parametrize("code", [errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS])
def test_refused_nowait_falls_back_once_per_filesystem(tmp_path: Path, code: int,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    data = _views(4)
    group = _store(tmp_path, data, [0, 1, 2])
    counting = _CountingPreadv({"nowait": code})
    monkeypatch.setattr(os, "preadv", counting)
    reader = ShardReader()
    _check_values(group, data, reader)
    assert counting.calls["nowait"] == 1
    assert not reader._fs[os.stat(group).st_dev].nowait


def test_refused_preadv_reads_with_pread(tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    data = _views(5)
    group = _store(tmp_path, data, [0, 2])
    for v in data.values():
        v[4:8] = 0  # shard 1 never written: zeros
    counting = _CountingPreadv({"nowait": errno.EOPNOTSUPP, "plain": errno.ENOSYS})
    monkeypatch.setattr(os, "preadv", counting)
    for verify in ("always", "once", "off"):
        reader = ShardReader(verify=verify, chunk_cache_bytes=0)  # type: ignore[arg-type]
        _check_values(group, data, reader)
        assert counting.calls == {"nowait": 1, "plain": 1}  # learned once per reader
        counting.calls = {"nowait": 0, "plain": 0}


def test_a_platform_without_preadv_reads(tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    data = _views(6)
    group = _store(tmp_path, data, [0, 1, 2])
    monkeypatch.delattr(os, "preadv")
    monkeypatch.delattr(os, "RWF_NOWAIT")
    monkeypatch.delattr(os, "posix_fadvise")
    reader = ShardReader()
    _check_values(group, data, reader)
    assert reader._fs[os.stat(group).st_dev] == FsReads(nowait=False, vectored=False)


def test_a_read_only_cache_reads(tmp_path: Path) -> None:
    data = _views(7)
    group = _store(tmp_path, data, [0, 1, 2])
    for path in sorted(tmp_path.rglob("*"), reverse=True):  # files before their folders
        mode = path.stat().st_mode
        path.chmod(mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    try:
        _check_values(group, data, ShardReader())
    finally:
        for path in tmp_path.rglob("*"):
            path.chmod(path.stat().st_mode | stat.S_IWUSR)


def test_other_read_errors_are_not_taken_for_unsupported(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    group = _store(tmp_path, _views(8), [0])
    monkeypatch.setattr(os, "preadv", _CountingPreadv({"nowait": errno.EIO}))
    with pytest.raises(OSError, match="Input/output error"):
        read_clip(group, NAMES, [0, 1], ShardReader())


def test_pread_fallback_fills_buffers_and_stops_at_the_end(tmp_path: Path) -> None:
    path = tmp_path / "f"
    path.write_bytes(bytes(range(10)))
    fd = os.open(path, os.O_RDONLY)
    try:
        bufs = [np.zeros(3, np.uint8), np.zeros(4, np.uint8), np.zeros(5, np.uint8)]
        assert read_each(fd, bufs, 1) == 9
        np.testing.assert_array_equal(np.concatenate(bufs), [*range(1, 10), 0, 0, 0])
    finally:
        os.close(fd)
    rest = skip([np.arange(3, dtype=np.uint8), np.arange(4, dtype=np.uint8)], 4)
    assert [r.tolist() for r in rest] == [[1, 2, 3]]
