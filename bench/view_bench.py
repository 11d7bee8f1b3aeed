"""View benchmark: writing the Rerun recording of one recording against reading the same views
from the cache, in the same run.

One synthetic recording (`seconds` long, 3 cameras at 10 Hz, `points` per sweep at 10 Hz) goes
through the stages in-process with geometry-only packets (the view reads g, never h). Then,
alternating, best of `repeats`: (a) `read`: every view's images, g and metadata read shard by
shard from the cache (`pipeline.analysis.view.source.shard_rows`, the view's own reader);
(b) `view`: the
whole `.rrd` written (the same reads, plus decoding each selected sweep from its bag, projecting
it, and logging). A third timing decodes the selected sweeps alone, the part of (b) that is
neither cache reading nor logging. Only ratios are meaningful on a shared machine.

Times come from `bench.measure.fastest` (wall and process CPU; `view_over_read_cpu` is
the CPU-time ratio, less disturbed by other jobs on a shared machine).
`rss_ratio_2x_length`: peak RSS (`measure.PeakRSS`) of a fresh interpreter writing the view of the
whole recording over one writing its first half (each after the same imports); flat memory reads
~1, and `rss_increment_mb_*` is the growth over the RSS after the imports.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.measure import fastest
from pipeline.analysis.view import source
from pipeline.analysis.view.writer import ViewOptions, ViewResult, plan, write_view
from pipeline.run.stage import Stage
from schemas.config import M3GDConfig, SynthConfig, config_to_dict, parse_config

_RSS_CHILD = """
import json, sys
from pathlib import Path
from bench.measure import PeakRSS
from pipeline.analysis.view.writer import ViewOptions, write_view
from schemas.config import parse_config
cfg = parse_config(json.loads(sys.argv[1]))
end = None if sys.argv[3] == "all" else float(sys.argv[3])
with PeakRSS(period_s=0.005) as rss:
    write_view(cfg, Path(sys.argv[2]), ViewOptions(end_s=end))
print(json.dumps({"base_mb": rss.base / 2**20, "peak_mb": (rss.base + rss.peak) / 2**20}))
"""


def _output(base: Path, seconds: float, points: int, stages: Sequence[Stage]) -> M3GDConfig:
    """Synthesize one recording and run the stage graph `stages` on it in-process; its config."""
    from pipeline.run.service import run_stages
    from pipeline.synth.api import synthesize

    synth = SynthConfig(seconds=seconds, points_per_sweep=points)
    mission = Path(str(synthesize(base / "rec", synth, "corridor", mission="b_view").mission_dir))
    cfg = parse_config({"output_dir": str(base / "out"),
                        "ingest": {"recordings": [str(mission)]},
                        "packets": {"mode": "geom_only"}, "dag": {"executor": "local"}})
    summaries = run_stages(cfg, list(stages)).summaries
    failed = {s.name: s.failed for s in summaries if s.failed}
    if failed:
        raise RuntimeError(f"benchmark run failed: {failed}")
    return cfg


def _read_all(cfg: M3GDConfig) -> int:
    """Read every view's arrays from the cache shard row by shard row; the views read."""
    src = source.open_recording(cfg, None, None)
    view_plan, _, _ = plan(src, ViewOptions())
    n = 0
    for row in source.shard_rows(src, view_plan):
        for batch in row:
            n += len(batch.frames)
            assert all(np.isfinite(a).all() for a in batch.arrays.values() if a.dtype.kind == "f")
    return n


def _decode_sweeps(cfg: M3GDConfig) -> int:
    """Decode every selected sweep from its bag once (one pass); the sweeps decoded."""
    src = source.open_recording(cfg, None, None)
    used = sorted({int(s) for c in src.cameras.values()
                   for s in c.selection["sweep"][c.selection["ok"]]})
    return sum(1 for _ in source.SweepReader(src).decode(used))


def peak_rss_mb(cfg: M3GDConfig, out: Path, end_s: float | None) -> dict[str, float]:
    """Peak RSS (MB, sampled every 5 ms) of a fresh interpreter writing the view up to `end_s`
    (None: all), and its RSS just before writing (after the imports)."""
    args = [sys.executable, "-c", _RSS_CHILD, json.dumps(config_to_dict(cfg), default=str),
            str(out), "all" if end_s is None else str(end_s)]
    proc = subprocess.run(args, capture_output=True, text=True, check=True)
    result: dict[str, float] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def run_view_bench(stages: Sequence[Stage], seconds: float = 10.0, points: int = 16384,
                   repeats: int = 3, workdir: Path | None = None) -> dict[str, Any]:
    """Figures of `m3gd bench view` (see the module docstring); `stages` is the stage graph
    (dags.graph.STAGES), handed in because pipeline may not import dags."""
    base = Path(tempfile.mkdtemp(prefix="m3gd-bench-view-", dir=workdir))
    try:
        cfg = _output(base, seconds, points, stages)
        jobs: dict[str, Any] = {
            "read": lambda: _read_all(cfg),
            "view": lambda: write_view(cfg, base / "view.rrd", ViewOptions()),
            "decode": lambda: _decode_sweeps(cfg)}
        best: dict[str, tuple[float, float]] = {}
        last: dict[str, Any] = {}
        for _ in range(repeats):  # alternating; the fastest wall and CPU time of each
            for name, fn in jobs.items():
                wall, cpu, last[name] = fastest(fn)
                prev = best.get(name, (math.inf, math.inf))
                best[name] = (min(prev[0], wall), min(prev[1], cpu))
        result = last["view"]
        assert isinstance(result, ViewResult) and result.views == last["read"]
        read_s, view_s, decode_s = best["read"][0], best["view"][0], best["decode"][0]
        jpeg = write_view(cfg, base / "view_jpeg.rrd", ViewOptions(jpeg_quality=90))
        minutes = result.duration_s / 60.0
        half = peak_rss_mb(cfg, base / "half.rrd", result.duration_s / 2)
        whole = peak_rss_mb(cfg, base / "whole.rrd", None)
        return {
            "view_seconds_per_recording_minute": view_s / minutes,
            "rrd_bytes_per_view": result.bytes / result.views,
            "rrd_bytes_per_view_jpeg90": jpeg.bytes / jpeg.views,
            "view_over_read": view_s / read_s,
            "view_over_read_cpu": best["view"][1] / best["read"][1],
            "view_s": view_s, "read_s": read_s, "view_cpu_s": best["view"][1],
            "read_cpu_s": best["read"][1], "sweep_decode_s": decode_s,
            "view_minus_decode_over_read": (view_s - decode_s) / read_s,
            "views": result.views, "sweeps": result.sweeps, "recording_s": result.duration_s,
            "points_per_sweep": points, "repeats": repeats,
            "rss_ratio_2x_length": whole["peak_mb"] / half["peak_mb"],
            "peak_rss_mb_half": half["peak_mb"], "peak_rss_mb_whole": whole["peak_mb"],
            "rss_increment_mb_half": half["peak_mb"] - half["base_mb"],
            "rss_increment_mb_whole": whole["peak_mb"] - whole["base_mb"],
        }
    finally:
        shutil.rmtree(base, ignore_errors=True)
