"""bench.worker_pool: a killed parent takes its pool workers with it (Linux)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

PARENT = textwrap.dedent('''
    import os, sys, time
    from pathlib import Path
    from bench.worker_pool import spawn_pool

    def job(where):
        Path(where).write_text(str(os.getpid()))
        time.sleep(120)

    if __name__ == "__main__":
        with spawn_pool(1) as pool:
            pool.submit(job, sys.argv[1]).result()
''')


def _alive(pid: int) -> bool:
    """Running or sleeping (a zombie waiting for a reaper counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux only")
def test_killing_the_parent_ends_its_workers(tmp_path: Path) -> None:
    script, pid_file = tmp_path / "parent.py", tmp_path / "worker.pid"
    script.write_text(PARENT)
    root = Path(__file__).resolve().parents[2]
    parent = subprocess.Popen([sys.executable, str(script), str(pid_file)], cwd=root,
                              env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})
    try:
        deadline = time.monotonic() + 60
        while not pid_file.exists() or not pid_file.read_text():
            assert time.monotonic() < deadline, "the worker never started"
            assert parent.poll() is None, "the parent exited early"
            time.sleep(0.1)
        worker = int(pid_file.read_text())
        assert _alive(worker)
        parent.kill()  # SIGKILL: no handler, no executor shutdown runs
        parent.wait()
        deadline = time.monotonic() + 10
        while _alive(worker):
            assert time.monotonic() < deadline, f"worker {worker} outlived its parent"
            time.sleep(0.1)
    finally:
        parent.kill()
