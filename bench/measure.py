"""What every benchmark measures with: time (wall and process CPU) and peak resident memory.

Two memory figures, for two situations:
- `PeakRSS`: the largest RSS above the RSS at entry, sampled by a thread while a block
  runs (in-process: the sampler's latency cells, an ingest in a fresh interpreter);
- `peak_rss_bytes`: the kernel's high-water mark of this whole process (`VmHWM` of
  /proc/self/status, reset by exec), for a child process that runs one measured job.
"""

from __future__ import annotations

import math
import resource
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import psutil


def fastest(fn: Callable[[], Any], repeats: int = 1) -> tuple[float, float, Any]:
    """Fastest wall and process-CPU seconds over `repeats` calls of fn, and the last result.

    CPU seconds (all threads of this process) are what one dedicated core would spend; on a
    shared, oversubscribed machine the wall time also counts time spent waiting for a core.
    """
    wall, cpu, out = math.inf, math.inf, None
    for _ in range(max(1, repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        out = fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall, cpu, out


class PeakRSS:
    """Context manager: peak RSS (bytes) above the entry RSS, sampled every `period_s`.

    After the block: `base` is the RSS at entry, `peak` the largest excess over it (>= 0).
    """

    def __init__(self, period_s: float = 1e-3) -> None:
        self.period_s, self.peak, self._stop = period_s, 0, threading.Event()
        self._proc = psutil.Process()

    def _watch(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self._proc.memory_info().rss - self.base)
            time.sleep(self.period_s)

    def __enter__(self) -> PeakRSS:
        self.base = self._proc.memory_info().rss
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._proc.memory_info().rss - self.base)


def peak_rss_bytes() -> dict[str, int]:
    """This process's peak RSS in bytes: {'vm_hwm': VmHWM, 'ru_maxrss': getrusage} (Linux).

    On Linux `ru_maxrss` can carry over from the parent across fork; VmHWM is reset by exec.
    """
    out = {"ru_maxrss": int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024}
    status = Path("/proc/self/status")
    if status.exists():
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                out["vm_hwm"] = int(line.split()[1]) * 1024  # kB
    out.setdefault("vm_hwm", out["ru_maxrss"])
    return out
