"""A process pool whose workers do not outlive the process that started them.

`ProcessPoolExecutor` workers are separate processes: when their parent is killed (SIGTERM or
SIGKILL, not a terminal's Ctrl-C, which reaches the whole process group) they go on with the
job they hold, for as long as it takes (a science run: 20 minutes), beside the rerun that
repeats it. On Linux each worker asks the kernel for SIGTERM when its parent dies
(`prctl(PR_SET_PDEATHSIG)`); elsewhere the pool is an ordinary one.
"""

from __future__ import annotations

import os
import signal
import sys
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

PR_SET_PDEATHSIG = 1
"""prctl option (linux/prctl.h): signal this process when its parent dies."""


def die_with_parent(parent_pid: int) -> None:
    """Pool initializer: SIGTERM this worker when `parent_pid` dies (Linux); exit at once if
    it died before the request was made (the worker was then re-parented)."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
        return  # not granted (a sandbox): an ordinary worker
    if os.getppid() != parent_pid:
        os._exit(1)


def spawn_pool(jobs: int) -> ProcessPoolExecutor:
    """`jobs` spawned worker processes that end with this process."""
    return ProcessPoolExecutor(jobs, mp_context=get_context("spawn"),
                               initializer=die_with_parent, initargs=(os.getpid(),))
