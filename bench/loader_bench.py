"""Loader benchmark: clips/s the streaming loader delivers against clips/s the tiny model trains.

Both rates are measured in the same run on the same cache:
  loader  `ClipStream` + `make_loader` over the 'train' split, with 0 and with N DataLoader
          workers (spawned); steady-state clips/s once every worker has delivered a batch,
          so the worker start-up (reported apart) is not counted. Epochs are chained until
          `min_clips` steady-state clips are read.
  model   `Trainer.step` of the tiny preset (sized from the cache) on batches taken from the
          same loader; clips/s = clips per batch / median seconds per step after a warm-up.
`loader_over_model` is the 0-worker (single-process, in the trainer's own thread) loader rate
over the model rate: the conservative figure, since workers only add parallel capacity.

Without a cache the benchmark builds one through the real pipeline (synth, then every stage
on the local executor) from a tiny configuration in a temporary directory.
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from model.compare import net_config_from_cache
from model.dataset import ClipStream, make_loader
from model.loop import model_batch
from model.train_step import TrainConfig, Trainer
from pipeline.run.stage import Stage
from schemas.config import M3GDConfig, parse_config
from schemas.errors import DataError


@dataclass(frozen=True)
class LoaderBenchSpec:
    """Sizes of the loader benchmark."""

    batch_size: int = 4
    mode: str = "full"
    preset: str = "tiny"
    workers: int = 2
    min_clips: int = 64
    model_steps: int = 5
    seed: int = 0


def tiny_config(out: Path) -> M3GDConfig:
    """Two 3 s synthetic recordings, front camera, 56 x 84 images (4 x 6 grid), C 588, C_u 8."""
    return parse_config({
        "output_dir": str(out),
        "synth": {"scenes": ["corridor", "plaza"], "seconds": 3.0, "cameras": ["front"],
                  "image_width": 168, "image_height": 112, "points_per_sweep": 2048,
                  "depth_maps": False},
        "ingest": {"cameras": ["front"], "out_height": 56, "out_width": 84},
        "encoders": {"image_channels": 588, "point_channels": 8},
        "cache": {"shard_views": 8}, "dag": {"executor": "local", "retries": 0},
        "clips": {"eval_clips_per_recording": 8, "eval_fraction": 0.5}})


def build_cache(cfg: M3GDConfig, stages: Sequence[Stage]) -> Path:
    """Run the graph `stages` for `cfg` on the local executor; return its output directory."""
    from pipeline.run.service import run_stages

    summaries = run_stages(cfg, list(stages)).summaries
    failed = {s.name: s.failed for s in summaries if s.failed}
    if failed:
        raise RuntimeError(f"building the benchmark cache failed: {failed}")
    return cfg.output_dir


def _stream(output_dir: Path, spec: LoaderBenchSpec) -> ClipStream:
    """The training-split stream the trainer would read."""
    return ClipStream(output_dir, "train", spec.mode, seed=spec.seed)


def _active_workers(stream: ClipStream, epoch: int, workers: int) -> int:
    """How many of `workers` DataLoader workers have clips in `epoch`."""
    total = max(workers, 1)
    return sum(1 for w in range(total) if stream.worker_clips(epoch, w, total))


def loader_rate(output_dir: Path, spec: LoaderBenchSpec, workers: int) -> dict[str, float]:
    """Steady-state clips/s of the loader with `workers` workers, and start-up seconds.

    Per epoch, timing starts once every worker that has clips has delivered its first batch
    (worker start-up and first reads excluded) and counts the clips after that; epochs are
    chained until `min_clips` steady-state clips are counted.
    """
    stream = _stream(output_dir, spec)
    if not stream.clips:
        raise DataError(f"{output_dir}: no training clip")
    steady_clips, steady_s, startups, epoch = 0, 0.0, [], 0
    while steady_clips < spec.min_clips:
        stream.set_epoch(epoch)
        active, seen = _active_workers(stream, epoch, workers), set()
        t0 = time.perf_counter()
        t_ready: float | None = None
        t_last = t0
        for batch in make_loader(stream, spec.batch_size, workers):
            t_last = time.perf_counter()  # worker shutdown after the last batch is not timed
            if t_ready is not None:
                steady_clips += int(batch["clip_id"].shape[0])
                continue
            seen.add(int(batch["_worker"][0]))
            if len(seen) == active:
                t_ready = t_last
                startups.append(t_ready - t0)
        if t_ready is not None:
            steady_s += t_last - t_ready
        epoch += 1
        if epoch > 1000:
            raise DataError(f"{output_dir}: too few clips ({len(stream.clips)}) to time the "
                             f"loader at batch size {spec.batch_size}")
    return {"clips_per_s": steady_clips / steady_s, "startup_s": statistics.fmean(startups),
            "epochs": float(epoch)}


def model_rate(output_dir: Path, spec: LoaderBenchSpec) -> dict[str, Any]:
    """Clips/s of `Trainer.step` (tiny preset sized from the cache) on real loader batches."""
    stream = _stream(output_dir, spec)
    net_cfg = net_config_from_cache(stream, spec.mode, spec.preset)
    trainer = Trainer(net_cfg, TrainConfig(lr=1e-3, seed=spec.seed))
    batches: list[dict[str, Tensor]] = []
    for batch in make_loader(stream, spec.batch_size):
        batches.append(model_batch(batch))
        if len(batches) > spec.model_steps:
            break
    trainer.step(batches[0])  # warm-up
    times, clips = [], []
    for i in range(spec.model_steps):
        b = batches[(i + 1) % len(batches)]
        t0 = time.perf_counter()
        trainer.step(b)
        times.append(time.perf_counter() - t0)
        clips.append(int(b["latents"].shape[0]))
    sec = statistics.median(times)
    return {"clips_per_s": statistics.fmean(clips) / sec, "s_per_step": sec,
            "net": net_cfg.to_json()}


def run_loader_bench(spec: LoaderBenchSpec, stages: Sequence[Stage],
                     output_dir: Path | None = None,
                     workdir: Path | None = None) -> dict[str, Any]:
    """Loader clips/s (0 and spec.workers workers) and model clips/s on one cache; ratios.

    output_dir: an existing pipeline output (cache.zarr + clips.parquet); None builds the tiny
    one of `tiny_config` with the graph `stages` (dags.graph.STAGES) under `workdir` (a
    temporary directory, removed afterwards).
    """
    torch.set_num_threads(1)
    tmp: Path | None = None
    if output_dir is None:
        tmp = Path(tempfile.mkdtemp(prefix="m3gd-bench-loader-", dir=workdir))
        t0 = time.perf_counter()
        output_dir = build_cache(tiny_config(tmp / "out"), stages)
        built_s: float | None = time.perf_counter() - t0
    else:
        built_s = None
    try:
        model = model_rate(output_dir, spec)
        single = loader_rate(output_dir, spec, 0)
        multi = loader_rate(output_dir, spec, spec.workers) if spec.workers else None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    out: dict[str, Any] = {
        "loader_over_model": single["clips_per_s"] / model["clips_per_s"],
        "loader_clips_per_s_0_workers": single["clips_per_s"],
        "model_clips_per_s": model["clips_per_s"],
        "model_s_per_step": model["s_per_step"],
    }
    if multi is not None:
        w = spec.workers
        out[f"loader_clips_per_s_{w}_workers"] = multi["clips_per_s"]
        out[f"loader_over_model_{w}_workers"] = multi["clips_per_s"] / model["clips_per_s"]
        out[f"startup_s_{w}_workers"] = multi["startup_s"]
    out |= {"goal_loader_over_model": 5.0,
            "cache": "built (tiny_config)" if built_s is not None else str(output_dir),
            "cache_build_s": built_s, "net": model["net"], "spec": asdict(spec)}
    return out
