"""Speed of `m3gd inspect` against reading every message of the same recording.

    python -m bench.inspect_speed RECORDING [RECORDING ...]

Prints, per recording: its size, the inspection's wall time (best of 3), the time to read
every message's raw bytes through the same reader (`BagFile.messages`, no decoding: the floor
of any tool that looks at every message), their ratio, and seconds per GB.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from pipeline.inspect.recording import inspect_recording
from pipeline.inspect.scan import open_bags


def read_all(path: Path) -> int:
    """Bytes of every message of every topic, read raw."""
    _, bags = open_bags(path)
    total = 0
    for bag in bags:
        for msg in bag.messages(list(bag.topics())):
            total += len(msg.raw)
        bag.close()
    return total


def main(paths: list[str]) -> None:
    """Measure each recording and print one line."""
    for p in map(Path, paths):
        runs = []
        for _ in range(3):
            t = time.perf_counter()
            ins = inspect_recording(p)
            runs.append(time.perf_counter() - t)
        t = time.perf_counter()
        read_all(p)
        full = time.perf_counter() - t
        gb = ins.bytes / 1e9
        best = min(runs)
        print(f"{p}: {ins.format}, {ins.bytes / 1e6:.0f} MB, inspect {best:.2f} s "
              f"({best / gb:.2f} s/GB), read every message {full:.2f} s, ratio "
              f"{best / full:.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
