"""The output lock (`pipeline.run.lock`), local folder and S3 object (moto server): exclusive,
names its holder, takes over the lock of a dead run of this host, refuses another host's until
unlocked or broken, released at the end of its with-block also when the block raises."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.run.lock import (
    LOCK_NAME,
    LockHeld,
    OutputLock,
    StoreLock,
    held_output,
    output_lock,
    unlock,
)
from pipeline.run.store_sync import client
from store.object_store import parse_url


def test_second_lock_names_holder(tmp_path: Path) -> None:
    with OutputLock(tmp_path), pytest.raises(LockHeld) as info:
        OutputLock(tmp_path).acquire()
    msg = str(info.value)
    assert socket.gethostname() in msg and f"pid {os.getpid()}" in msg and "started" in msg
    assert not (tmp_path / LOCK_NAME).exists()


def test_stale_lock_of_dead_process_is_taken_over(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    holder = {"host": socket.gethostname(), "pid": pid, "started_unix_s": 1.0}
    (tmp_path / LOCK_NAME).write_text(json.dumps(holder))
    lock = OutputLock(tmp_path)
    lock.acquire()
    assert lock.took_over is not None and lock.took_over.pid == pid
    assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == os.getpid()
    lock.release()


def test_lock_on_other_host_is_respected(tmp_path: Path) -> None:
    holder = {"host": "elsewhere.example", "pid": 1, "started_unix_s": 1.0}
    (tmp_path / LOCK_NAME).write_text(json.dumps(holder))
    with pytest.raises(LockHeld, match=r"elsewhere\.example"):
        OutputLock(tmp_path).acquire()


def test_concurrent_starts_never_hold_the_lock_together(tmp_path: Path) -> None:
    """Was: a competitor reading the lock between O_EXCL create and fill called it stale."""
    from bench.support.lock_race import race

    for k, stale in enumerate((False, True, False, True)):
        r = race(tmp_path / f"d{k}", n=6, stale=stale, hold_s=0.2)
        assert r["double_holds"] == 0 and r["held"] >= 1, r
        assert r["lock_left"] == 0  # released and unlinked


def test_other_host_lock_says_what_to_do_and_can_be_broken(tmp_path: Path) -> None:
    holder = {"host": "elsewhere.example", "pid": 1, "started_unix_s": 1.0}
    (tmp_path / LOCK_NAME).write_text(json.dumps(holder))
    with pytest.raises(LockHeld, match=r"another host .*m3gd unlock .*--break-lock"):
        OutputLock(tmp_path).acquire()
    lock = OutputLock(tmp_path, break_lock=True)
    lock.acquire()
    assert lock.took_over is not None and lock.took_over.host == "elsewhere.example"
    lock.release()
    (tmp_path / LOCK_NAME).write_text(json.dumps(holder))
    old = unlock(tmp_path)
    assert old is not None and old.host == "elsewhere.example"
    assert not (tmp_path / LOCK_NAME).exists()
    OutputLock(tmp_path).acquire()


def test_unlock_refuses_a_live_run(tmp_path: Path) -> None:
    with OutputLock(tmp_path), pytest.raises(LockHeld, match="locked by another m3gd run"):
        unlock(tmp_path)


def test_release_on_exception(tmp_path: Path) -> None:
    with pytest.raises(KeyError), held_output(tmp_path) as lock:
        assert (tmp_path / LOCK_NAME).exists() and isinstance(lock, OutputLock)
        raise KeyError("a stage failed")
    assert not (tmp_path / LOCK_NAME).exists()
    with OutputLock(tmp_path) as again:
        assert again.took_over is None  # released, not left for a takeover


def _plant(url: str, host: str, pid: int) -> None:
    """A lock object as another run would have left it."""
    u = parse_url(url)
    client().put_object(Bucket=u.bucket, Key=f"{u.prefix}/.m3gd.lock",
                        Body=json.dumps({"host": host, "pid": pid, "started_unix_s": 0.0}))


def _dead_pid() -> int:
    """The pid of a process that has exited."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_s3_second_run_is_refused_until_release(s3: str) -> None:
    first = output_lock(s3)
    assert isinstance(first, StoreLock)
    with first:
        with pytest.raises(LockHeld, match=rf"^{s3} is locked by another m3gd run \(host "):
            StoreLock(s3).acquire()
        # the conditional write itself refuses: no check-then-put race to win
        assert not StoreLock(s3)._create()
    with StoreLock(s3) as again:
        assert again.took_over is None


def test_s3_release_leaves_a_lock_that_is_not_ours(s3: str) -> None:
    lock = StoreLock(s3)
    lock.acquire()
    _plant(s3, "other-host", 1)  # replaced behind our back (e.g. broken by a user)
    lock.release()
    assert StoreLock(s3).read()[0].host == "other-host"  # type: ignore[union-attr]


def test_s3_dead_run_of_this_host_is_taken_over(s3: str) -> None:
    _plant(s3, socket.gethostname(), _dead_pid())
    with StoreLock(s3) as lock:
        assert lock.took_over is not None and lock.took_over.host == socket.gethostname()


def test_s3_other_host_is_refused_then_unlocked_or_broken(s3: str) -> None:
    _plant(s3, "elsewhere", 4242)
    with pytest.raises(LockHeld, match=r"another host .*m3gd unlock s3://"):
        StoreLock(s3).acquire()
    with StoreLock(s3, break_lock=True) as lock:
        assert lock.took_over is not None and lock.took_over.host == "elsewhere"
    _plant(s3, "elsewhere", 4242)
    old = unlock(s3)  # type: ignore[arg-type]
    assert old is not None and old.host == "elsewhere"
    assert unlock(s3) is None  # type: ignore[arg-type]
    with StoreLock(s3), pytest.raises(LockHeld, match="running"):
        unlock(s3)  # type: ignore[arg-type]


def test_s3_release_on_exception(s3: str) -> None:
    with pytest.raises(KeyError), held_output(s3) as lock:  # type: ignore[arg-type]
        assert isinstance(lock, StoreLock) and lock.read()[0] == lock.me
        raise KeyError("a stage failed")
    assert StoreLock(s3).read() == (None, None)
