"""The whole DAG on tiny synthetic recordings: executors agree, kills are survived."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from dags.graph import STAGES
from pipeline.run.executors import DaskExecutor
from pipeline.run.runner import Runner
from pipeline.run.service import run_stages
from pipeline.stages.common import point_encoder
from tests.dags.conftest import tiny_config, write_config
from tests.dags.outputs import assert_same_outputs

pytestmark = pytest.mark.filterwarnings("ignore")


POINT_ENCODES: dict[str, int] = {}


@pytest.fixture(scope="module")
def reference(recordings: list[Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An uninterrupted in-process run, the reference output."""
    out = tmp_path_factory.mktemp("reference")
    cfg = tiny_config(out, recordings)
    point_encoder.cache_clear()
    summaries = run_stages(cfg, STAGES).summaries
    assert all(not s.failed for s in summaries), [s.failed for s in summaries]
    POINT_ENCODES["reference"] = point_encoder(cfg.encoders).n_encoded
    return out


def test_reference_run_is_complete(reference: Path) -> None:
    assert (reference / "clips.parquet").exists()
    assert (reference / "stats" / "view_stats").exists()
    assert (reference / "manifest.json").exists()
    clips = pq.read_table(reference / "clips.parquet").to_pylist()
    per_rec: dict[str, int] = {}
    for c in clips:
        if c["split"] == "eval":
            per_rec[c["recording"]] = per_rec.get(c["recording"], 0) + 1
    assert per_rec and set(per_rec.values()) == {10}  # eval_clips_per_recording, exactly


def test_each_selected_sweep_encoded_once_across_three_cameras(reference: Path) -> None:
    selected = set()
    for sel in sorted(reference.glob("index/*/selection.parquet")):
        rows = pq.read_table(sel).to_pylist()
        assert {r["camera"] for r in rows} == {"front", "left", "right"}
        selected |= {(sel.parent.name, r["sweep"]) for r in rows if r["status"] == "ok"}
    assert len(selected) > 0
    assert POINT_ENCODES["reference"] == len(selected)


def test_local_cluster_equals_in_process(reference: Path, recordings: list[Path],
                                        tmp_path: Path) -> None:
    executor = DaskExecutor(workers=2)
    try:
        Runner(tiny_config(tmp_path, recordings), STAGES, progress=False).run(executor)
    finally:
        executor.close()
    assert_same_outputs(reference, tmp_path)


def _first_mark(out: Path, stage: str, timeout: float = 300.0) -> bool:
    """Wait until some shard of `stage` is marked done under `out`."""
    end = time.time() + timeout
    while time.time() < end:
        if any(out.glob(f"cache_done/*/*/{stage}.*.json")):
            return True
        time.sleep(0.05)
    return False


def test_killed_worker_is_survived(reference: Path, recordings: list[Path],
                                   tmp_path: Path) -> None:
    executor = DaskExecutor(workers=2)
    killed: list[int] = []

    def killer() -> None:
        if _first_mark(tmp_path, "encode"):
            pids = executor.client.run(os.getpid)
            pid = sorted(pids.values())[0]
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    try:
        summaries = Runner(tiny_config(tmp_path, recordings), STAGES, progress=False).run(executor)
    finally:
        executor.close()
    thread.join(timeout=5)
    assert killed, "the test must kill a worker"
    assert all(not s.failed for s in summaries)
    assert_same_outputs(reference, tmp_path)


def test_sigkilled_run_resumes_to_same_outputs(reference: Path, recordings: list[Path],
                                               tmp_path: Path) -> None:
    out = tmp_path / "out"
    cfg = write_config(tmp_path / "cfg.yaml", out, recordings)
    cmd = [sys.executable, "-m", "cli", "-q", "-c", str(cfg), "run", "--workers", "2"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        assert _first_mark(out, "packets"), "the run never reached the packets stage"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert (out / ".m3gd.lock").exists()  # the dead run's lock is left behind
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert_same_outputs(reference, out)
