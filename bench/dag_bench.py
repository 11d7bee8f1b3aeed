"""DAG benchmark: the same recordings through the stage graph on 1 and on 2 Dask workers.

Recordings are synthesized once; each run writes a fresh output directory. The
speed-up is reported for the CPU-bound stages (ingest, encode, packets) and for
the whole run; per-item costs feed docs/scaling.md.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path

from pipeline.run.stage import Stage
from schemas.config import M3GDConfig, SynthConfig, parse_config

CPU_STAGES = ("ingest", "encode", "packets")


def _config(out: Path, recordings: list[Path], workers: int, packet_items: str = "auto",
            shard_views: int = 64) -> M3GDConfig:
    """The benchmark config: default sizes (224x336 images, C_u 1224), given workers."""
    return parse_config({"output_dir": str(out),
                         "ingest": {"recordings": [str(r) for r in recordings]},
                         "packets": {"items": packet_items},
                         "cache": {"shard_views": shard_views},
                         "dag": {"workers": workers}})


def _run(cfg: M3GDConfig, stages: Sequence[Stage]) -> dict[str, float]:
    """Run every stage on a new LocalCluster; return seconds per stage."""
    from pipeline.run.executors import DaskExecutor
    from pipeline.run.runner import Runner

    executor = DaskExecutor(cfg.dag.workers)
    try:
        summaries = Runner(cfg, list(stages), progress=False).run(executor)
    finally:
        executor.close()
    failed = {s.name: s.failed for s in summaries if s.failed}
    if failed:
        raise RuntimeError(f"benchmark run failed: {failed}")
    return {s.name: s.seconds for s in summaries} | {
        f"{s.name}_done": float(s.done) for s in summaries} | {
        f"{s.name}_n_items": float(s.items) for s in summaries}


def run_dag_bench(stages: Sequence[Stage], seconds: float = 4.0, recordings: int = 4,
                  packet_items: str = "auto", shard_views: int = 64) -> dict[str, float]:
    """Seconds per stage of the graph `stages` (dags.graph.STAGES) on 1 and 2 workers, and
    the speed-ups.

    With `packet_items="recording"` packets are one item per recording (each selected
    sweep is encoded once per recording), so the recordings' costs must spread over the
    workers: with 2 unequal recordings the slower one bounds the 2-worker time; 4 (one
    per scene) is the default. `"shard_row"` splits them per shard row of `shard_views`;
    `"auto"` (default) plans per worker count (`pipeline.stages.packets_plan`). The
    figures `packets_items_1_worker` / `_2_workers` count the items each plan made.
    (`<stage>_items` is, as before, the views or images the stage produced.)
    """
    from pipeline.synth.api import synthesize

    base = Path(tempfile.mkdtemp(prefix="m3gd-bench-dag-"))
    try:
        synth = SynthConfig(seconds=seconds)
        scenes = ["corridor", "warehouse", "forest", "plaza"][:recordings]
        missions = [Path(str(synthesize(base / "rec", synth, s, mission=f"b_{s}").mission_dir))
                    for s in scenes]
        one = _run(_config(base / "w1", missions, 1, packet_items, shard_views), stages)
        two = _run(_config(base / "w2", missions, 2, packet_items, shard_views), stages)
        cpu1 = sum(one[s] for s in CPU_STAGES)
        cpu2 = sum(two[s] for s in CPU_STAGES)
        out = {"speedup_2_workers": cpu1 / cpu2,
               "speedup_2_workers_all_stages": sum(one[s] for s in one if "_" not in s)
               / sum(two[s] for s in two if "_" not in s)}
        out["packets_items_1_worker"] = one["packets_n_items"]
        out["packets_items_2_workers"] = two["packets_n_items"]
        for stage in CPU_STAGES:
            out[f"{stage}_s_1_worker"] = one[stage]
            out[f"{stage}_s_2_workers"] = two[stage]
            out[f"{stage}_items"] = one[f"{stage}_done"]
            out[f"{stage}_speedup"] = one[stage] / two[stage]
        return out
    finally:
        shutil.rmtree(base, ignore_errors=True)
