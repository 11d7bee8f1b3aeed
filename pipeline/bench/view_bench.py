"""View benchmark: writing the Rerun recording of one recording against reading the same views
from the cache, in the same run.

One synthetic recording (`seconds` long, 3 cameras at 10 Hz, `points` per sweep at 10 Hz) goes
through the stages in-process with geometry-only packets (the view reads g, never h). Then,
alternating, best of `repeats`: (a) `read`: every view's images, g and metadata read shard by
shard from the cache (`pipeline.view.source.shard_rows`, the view's own reader); (b) `view`: the
whole `.rrd` written (the same reads, plus decoding each selected sweep from its bag, projecting
it, and logging). A third timing decodes the selected sweeps alone, the part of (b) that is
neither cache reading nor logging. Only ratios are meaningful on a shared machine.

`rss_ratio_2x_length`: peak RSS of a fresh interpreter writing the view of the whole recording
over one writing its first half (sampled from outside; each after the same imports); flat memory
reads ~1, and `rss_increment_mb_*` is the growth over the RSS after the imports.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from pipeline.view import source
from pipeline.view.writer import ViewOptions, plan, write_view
from schemas.config import M3GDConfig, SynthConfig, config_to_dict, parse_config

_RSS_CHILD = """
import json, sys
from pathlib import Path
from pipeline.view.writer import ViewOptions, write_view
from schemas.config import parse_config
cfg = parse_config(json.loads(sys.argv[1]))
end = None if sys.argv[3] == "all" else float(sys.argv[3])
print("ready", flush=True)
sys.stdin.readline()
write_view(cfg, Path(sys.argv[2]), ViewOptions(end_s=end))
"""
"""Child: imports, says ready, waits for the go (so the parent has its resting RSS), writes."""


def _output(base: Path, seconds: float, points: int) -> M3GDConfig:
    """Synthesize one recording and run every stage on it in-process; its config."""
    from dags.graph import STAGES
    from pipeline.run.executors import LocalExecutor
    from pipeline.run.runner import Runner
    from pipeline.synth.api import synthesize

    synth = SynthConfig(seconds=seconds, points_per_sweep=points)
    mission = Path(str(synthesize(base / "rec", synth, "corridor", mission="b_view").mission_dir))
    cfg = parse_config({"output_dir": str(base / "out"),
                        "ingest": {"recordings": [str(mission)]},
                        "packets": {"mode": "geom_only"}, "dag": {"executor": "local"}})
    failed = {s.name: s.failed for s in Runner(cfg, STAGES, progress=False).run(LocalExecutor())
              if s.failed}
    if failed:
        raise RuntimeError(f"benchmark run failed: {failed}")
    return cfg


def _read_all(cfg: M3GDConfig) -> tuple[float, int]:
    """Seconds to read every view's arrays from the cache shard by shard; views read."""
    t0 = time.perf_counter()
    src = source.open_recording(cfg, None, None)
    view_plan, _, _ = plan(src, ViewOptions())
    n = 0
    for row in source.shard_rows(src, view_plan):
        for batch in row:
            n += len(batch.frames)
            assert all(np.isfinite(a).all() for a in batch.arrays.values() if a.dtype.kind == "f")
    return time.perf_counter() - t0, n


def _decode_sweeps(cfg: M3GDConfig) -> tuple[float, int]:
    """Seconds to decode every selected sweep from its bag once; sweeps decoded."""
    src = source.open_recording(cfg, None, None)
    used = sorted({int(s) for c in src.cameras.values()
                   for s in c.selection["sweep"][c.selection["ok"]]})
    t0 = time.perf_counter()
    n = sum(1 for _ in source.SweepReader(src).decode(used))
    return time.perf_counter() - t0, n


def peak_rss_mb(cfg: M3GDConfig, out: Path, end_s: float | None) -> dict[str, float]:
    """Peak RSS (MB, sampled every 5 ms by this process) of a fresh interpreter writing the view
    up to `end_s` (None: all), and its RSS after the imports, before writing."""
    args = [sys.executable, "-c", _RSS_CHILD, json.dumps(config_to_dict(cfg), default=str),
            str(out), "all" if end_s is None else str(end_s)]
    with subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) as p:
        assert p.stdin is not None and p.stdout is not None
        if p.stdout.readline().strip() != "ready":
            raise RuntimeError("the view child did not start")
        child = psutil.Process(p.pid)
        base = peak = child.memory_info().rss
        p.stdin.write("go\n")
        p.stdin.flush()
        while p.poll() is None:
            try:
                peak = max(peak, child.memory_info().rss)
            except psutil.NoSuchProcess:
                break
            time.sleep(0.005)
    if p.returncode:
        raise RuntimeError(f"the view child failed with code {p.returncode}")
    return {"base_mb": base / 2**20, "peak_mb": peak / 2**20}


def run_view_bench(seconds: float = 10.0, points: int = 16384, repeats: int = 3,
                   workdir: Path | None = None) -> dict[str, Any]:
    """Figures of `m3gd bench view` (see the module docstring)."""
    base = Path(tempfile.mkdtemp(prefix="m3gd-bench-view-", dir=workdir))
    try:
        cfg = _output(base, seconds, points)
        read_s, view_s, decode_s = [], [], []
        result = None
        for _ in range(repeats):
            t, n_read = _read_all(cfg)
            read_s.append(t)
            t0 = time.perf_counter()
            result = write_view(cfg, base / "view.rrd", ViewOptions())
            view_s.append(time.perf_counter() - t0)
            decode_s.append(_decode_sweeps(cfg)[0])
        assert result is not None and result.views == n_read
        jpeg = write_view(cfg, base / "view_jpeg.rrd", ViewOptions(jpeg_quality=90))
        minutes = result.duration_s / 60.0
        half = peak_rss_mb(cfg, base / "half.rrd", result.duration_s / 2)
        whole = peak_rss_mb(cfg, base / "whole.rrd", None)
        return {
            "view_seconds_per_recording_minute": min(view_s) / minutes,
            "rrd_bytes_per_view": result.bytes / result.views,
            "rrd_bytes_per_view_jpeg90": jpeg.bytes / jpeg.views,
            "view_over_read": min(view_s) / min(read_s),
            "view_s": min(view_s), "read_s": min(read_s),
            "sweep_decode_s": min(decode_s),
            "view_minus_decode_over_read": (min(view_s) - min(decode_s)) / min(read_s),
            "views": result.views, "sweeps": result.sweeps, "recording_s": result.duration_s,
            "points_per_sweep": points, "repeats": repeats,
            "rss_ratio_2x_length": whole["peak_mb"] / half["peak_mb"],
            "peak_rss_mb_half": half["peak_mb"], "peak_rss_mb_whole": whole["peak_mb"],
            "rss_increment_mb_half": half["peak_mb"] - half["base_mb"],
            "rss_increment_mb_whole": whole["peak_mb"] - whole["base_mb"],
        }
    finally:
        shutil.rmtree(base, ignore_errors=True)
