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

`warp_host_cost_over_no_lidar` (goal <= 1.1): the host time of a training step in packet
mode 'warp' over that of 'no_lidar': a no_lidar `Trainer.step` plus the warp channels as
computed within a warp step (same cache, same clips, steps interleaved so that both see the
same machine load), by the batched torch path on the batch's device (`model.warp_device`);
`..._host_path` the same with the numpy path on the host (`model.adapter.warp_channels_host`,
the path before), timed in the same run. The bench runs on the CPU, where the device path's
arithmetic is host time too (an upper bound of its host cost on a GPU, where it is only the
launches). `warp_step_over_no_lidar[_host_path]` is the whole steps' ratio, which also
counts the warp adapter's wider input (arithmetic, the device's on a GPU).

Without a cache the benchmark builds one through the real pipeline (synth, then every stage
on the local executor) from a tiny configuration in a temporary directory.
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
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


@contextmanager
def warp_path(host: bool, spent: list[float]) -> Iterator[None]:
    """Within the block the warp modes compute their channels by the host path (numpy,
    `model.adapter.warp_channels_host`, the path before the device one) if `host`, else by
    the device path, and every call's seconds are appended to `spent`."""
    import model.adapter as adapter
    from model.warp_device import warp_channels_device

    saved = adapter.warp_channels
    inner = adapter.warp_channels_host if host else warp_channels_device

    def timed(*args: Any) -> Tensor:
        t0 = time.perf_counter()
        out = inner(*args)
        spent.append(time.perf_counter() - t0)
        return out

    adapter.warp_channels = timed  # type: ignore[assignment]
    try:
        yield
    finally:
        adapter.warp_channels = saved


def _trainer_and_batches(output_dir: Path, spec: LoaderBenchSpec, mode: str, n: int
                         ) -> tuple[Trainer, list[dict[str, Tensor]]]:
    """A tiny-preset trainer of packet `mode` and the first `n` model batches of its stream."""
    stream = ClipStream(output_dir, "train", mode, seed=spec.seed)
    trainer = Trainer(net_config_from_cache(stream, mode, spec.preset),
                      TrainConfig(lr=1e-3, seed=spec.seed))
    batches: list[dict[str, Tensor]] = []
    for batch in make_loader(stream, spec.batch_size):
        batches.append(model_batch(batch))
        if len(batches) >= n:
            break
    return trainer, batches


def _timed_step(trainer: Trainer, batch: dict[str, Tensor]) -> float:
    """Seconds of one `Trainer.step`."""
    t0 = time.perf_counter()
    trainer.step(batch)
    return time.perf_counter() - t0


def warp_cost(output_dir: Path, spec: LoaderBenchSpec) -> dict[str, float]:
    """Seconds per `Trainer.step` of no_lidar, of warp with the device path and of warp with
    the host path, the three interleaved step by step over spec.model_steps rounds after one
    warm-up round; the seconds the warp channels took within the warp steps; medians.

    warp_host_cost_over_no_lidar[_host_path]: (no_lidar step + warp channels) / no_lidar
    step, the host time a warp step adds to a no_lidar one (module doc);
    warp_step_over_no_lidar[_host_path]: the whole steps' ratio, which also counts the
    adapter's wider input (C + 1 more channels: arithmetic, the device's on a GPU).
    """
    n = max(spec.model_steps, 1)
    base, base_batches = _trainer_and_batches(output_dir, spec, "no_lidar", n)
    warp, warp_batches = _trainer_and_batches(output_dir, spec, "warp", n)
    times: dict[str, list[float]] = {k: [] for k in ("no_lidar", "warp", "warp_host_path",
                                                     "channels", "channels_host_path")}
    for i in range(n + 1):
        b, w = base_batches[i % len(base_batches)], warp_batches[i % len(warp_batches)]
        t = {"no_lidar": _timed_step(base, b)}
        for host, key in ((False, "warp"), (True, "warp_host_path")):
            spent: list[float] = []
            with warp_path(host, spent):
                t[key] = _timed_step(warp, w)
            t[key.replace("warp", "channels")] = sum(spent)
        if i:  # round 0 is the warm-up
            for k, v in t.items():
                times[k].append(v)
    med = {k: statistics.median(v) for k, v in times.items()}
    base_s = med["no_lidar"]
    return {"warp_host_cost_over_no_lidar": (base_s + med["channels"]) / base_s,
            "warp_host_cost_over_no_lidar_host_path":
                (base_s + med["channels_host_path"]) / base_s,
            "warp_step_over_no_lidar": med["warp"] / base_s,
            "warp_step_over_no_lidar_host_path": med["warp_host_path"] / base_s,
            "s_per_step_no_lidar": base_s, "s_per_step_warp": med["warp"],
            "s_per_step_warp_host_path": med["warp_host_path"],
            "s_warp_channels": med["channels"], "s_warp_channels_host_path":
                med["channels_host_path"]}


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
        warp = warp_cost(output_dir, spec)
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
    out |= {**warp, "goal_loader_over_model": 5.0, "goal_warp_host_cost_over_no_lidar": 1.1,
            "cache": "built (tiny_config)" if built_s is not None else str(output_dir),
            "cache_build_s": built_s, "net": model["net"], "spec": asdict(spec)}
    return out
