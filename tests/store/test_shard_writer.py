"""Shard files written in few writev calls: short writes resume where they stopped."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest

from store import shard_writer
from store.shard_writer import ShardWriter, writev_all


def test_short_writes_resume_where_they_stopped(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A writev that takes at most 7 bytes (and at most 3 buffers) still writes every
    buffer once, in order, empty ones skipped."""
    real = os.writev
    calls = []

    def short(fd: int, buffers: list[memoryview]) -> int:
        calls.append(len(buffers))
        return real(fd, [bytes(memoryview(b"".join(bytes(b) for b in buffers))[:7])])

    monkeypatch.setattr(shard_writer.os, "writev", short)
    monkeypatch.setattr(shard_writer, "IOV_MAX", 3)
    parts = [b"abc", b"", np.arange(10, dtype=np.uint8).data, b"0123456789abcdef", b"z"]
    with (tmp_path / "f").open("wb") as f:
        writev_all(f.fileno(), parts)
    assert (tmp_path / "f").read_bytes() == b"".join(bytes(p) for p in parts)
    assert max(calls) <= 3 and len(calls) == -(-30 // 7)


def test_every_buffer_in_one_call_when_the_system_takes_them(tmp_path: Path) -> None:
    parts = [np.full(1000, i, np.uint8).data for i in range(5)]
    with (tmp_path / "f").open("wb") as f:
        writev_all(f.fileno(), parts)
    assert (tmp_path / "f").read_bytes() == b"".join(bytes(p) for p in parts)


def test_two_queued_writes_run_at_once() -> None:
    """Two writes that wait for each other (a barrier of 2) finish only when both run at
    once; one writer thread runs them one after the other and the barrier breaks."""
    for threads, timeout in ((2, 30.0), (1, 0.3)):
        barrier = threading.Barrier(2, timeout=timeout)
        with ShardWriter(threads=threads) as writer:
            writer.submit(barrier.wait)
            writer.submit(barrier.wait)
            if threads == 1:
                with pytest.raises(threading.BrokenBarrierError):
                    writer.wait()


def test_a_body_error_drops_the_writes_not_yet_started() -> None:
    """The caller's error ends the block: the running write finishes, the queued ones never
    start (their work would be thrown away), and the caller's error is the one raised."""
    started, release, ran = threading.Event(), threading.Event(), []

    def first() -> None:
        started.set()
        release.wait(30)
        ran.append("first")

    timer = threading.Timer(2.0, release.set)  # lets the running write end after the cancel
    with pytest.raises(KeyError, match="body"), ShardWriter(threads=1) as writer:
        writer.submit(first)
        for k in range(3):
            writer.submit(ran.append, k)
        assert started.wait(30)
        timer.start()
        raise KeyError("body")
    timer.join()
    assert ran == ["first"]
