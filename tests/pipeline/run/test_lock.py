"""Output lock: exclusive, names its holder, takes over stale locks."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.run.lock import LOCK_NAME, LockHeld, OutputLock


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
    from pipeline.run.locking import unlock

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
    from pipeline.run.locking import unlock

    with OutputLock(tmp_path), pytest.raises(LockHeld, match="locked by another m3gd run"):
        unlock(tmp_path)
