"""The output lock on S3 (moto server): a conditional PUT, refused while held, a dead run's
lock taken over on its own host, another host's refused until unlocked or broken."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import pytest

from pipeline.run.lock import LockHeld
from pipeline.run.locking import output_lock, unlock
from pipeline.run.store_lock import StoreLock
from pipeline.run.store_sync import client
from store.object_store import parse_url


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


def test_second_run_is_refused_until_release(s3: str) -> None:
    first = output_lock(s3)
    assert isinstance(first, StoreLock)
    with first:
        with pytest.raises(LockHeld, match=rf"^{s3} is locked by another m3gd run \(host "):
            StoreLock(s3).acquire()
        # the conditional write itself refuses: no check-then-put race to win
        assert not StoreLock(s3)._create()
    with StoreLock(s3) as again:
        assert again.took_over is None


def test_release_leaves_a_lock_that_is_not_ours(s3: str) -> None:
    lock = StoreLock(s3)
    lock.acquire()
    _plant(s3, "other-host", 1)  # replaced behind our back (e.g. broken by a user)
    lock.release()
    assert StoreLock(s3).read()[0].host == "other-host"  # type: ignore[union-attr]


def test_dead_run_of_this_host_is_taken_over(s3: str) -> None:
    _plant(s3, socket.gethostname(), _dead_pid())
    with StoreLock(s3) as lock:
        assert lock.took_over is not None and lock.took_over.host == socket.gethostname()


def test_other_host_is_refused_then_unlocked_or_broken(s3: str) -> None:
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
