"""Concurrent starts against one output lock: how often two processes held it at once.

N processes (forked) wait for a common start time, try `OutputLock.acquire` once, and when they
get it hold it for `hold_s` before releasing. Each reports the monotonic interval it held the
lock; two intervals that overlap are a double hold. Optionally a stale lock of a dead process
(this host) is left in place first, so every contender is also racing to take it over.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from pipeline.run.lock import LOCK_NAME, LockHeld, OutputLock


def _contender(out_dir: str, start_at: float, hold_s: float, queue: Any) -> None:
    """One start: acquire at `start_at` (time.time), hold, release; report (t0, t1) or None."""
    time.sleep(max(0.0, start_at - time.time()))
    lock = OutputLock(Path(out_dir))
    try:
        lock.acquire()
    except LockHeld:
        queue.put(None)
        return
    t0 = time.monotonic()
    time.sleep(hold_s)
    t1 = time.monotonic()
    lock.release()
    queue.put((t0, t1))


def dead_pid() -> int:
    """The pid of a process that has exited."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    return int(done.stdout)


def write_stale_lock(out_dir: Path) -> None:
    """A lock file of a dead process on this host (as a killed run leaves it)."""
    holder = {"host": socket.gethostname(), "pid": dead_pid(), "started_unix_s": 1.0}
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / LOCK_NAME).write_text(json.dumps(holder))


def race(out_dir: Path, n: int = 8, stale: bool = False, hold_s: float = 0.3) -> dict[str, int]:
    """Start `n` contenders at once; counts of winners and of starts that overlapped another."""
    if stale:
        write_stale_lock(out_dir)
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    start_at = time.time() + 0.3
    procs = [ctx.Process(target=_contender, args=(str(out_dir), start_at, hold_s, queue))
             for _ in range(n)]  # fmt: skip
    for p in procs:
        p.start()
    held = [r for r in (queue.get(timeout=60) for _ in procs) if r is not None]
    for p in procs:
        p.join(timeout=30)
    overlapping = sum(
        any(i != j and a[0] < b[1] and b[0] < a[1] for j, b in enumerate(held))
        for i, a in enumerate(held)
    )
    return {"starts": n, "held": len(held), "double_holds": overlapping,
            "lock_left": int((out_dir / LOCK_NAME).exists())}  # fmt: skip


def race_trials(root: Path, trials: int = 5, n: int = 8) -> dict[str, int]:
    """`trials` races on fresh and on stale-locked folders; total starts and double holds."""
    total = {"starts": 0, "double_holds": 0, "trials": 0}
    for k in range(trials):
        for stale in (False, True):
            r = race(root / f"race{k}_{int(stale)}", n, stale)
            total["starts"] += r["starts"]
            total["double_holds"] += r["double_holds"]
            total["trials"] += 1
    os.sync()
    return total
