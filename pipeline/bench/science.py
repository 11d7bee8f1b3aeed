"""Science benchmark (issue 14): does the trained model beat trivial baselines, what does
LiDAR add, and what does sampling speed cost in quality.

One command (`m3gd bench science --json`) builds a synthetic cache through the real pipeline
(many short recordings: every scene at several synth seeds, so the model sees variety),
trains one model per (packet mode, seed), and scores held-out targets beside the
copy-nearest-source and dataset-mean-latent baselines on the same targets.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from torch import Tensor

from model.compare import net_config_from_cache
from model.dataset import ClipStream, load_clips
from model.loop import model_batch, train_loop
from model.net import M3GDNet, NetConfig
from model.scoring import eval_batches, image_decoder, score_clips, summarize
from model.train_step import TrainConfig, Trainer
from model.validation import t_binned_loss
from schemas.config import M3GDConfig, parse_config

SCENES = ("corridor", "warehouse", "forest", "plaza")


@dataclass(frozen=True)
class ScienceData:
    """The synthetic data set of the science bench."""

    synth_seeds: tuple[int, ...] = (0, 1, 2, 3)
    seconds: float = 10.0
    out_hw: tuple[int, int] = (56, 84)
    image_channels: int = 588
    point_channels: int = 8
    points_per_sweep: int = 4096
    gap_max: int = 6
    eval_fraction: float = 0.25
    eval_clips_per_recording: int = 24


def science_config(out: Path, data: ScienceData) -> M3GDConfig:
    """Pipeline config of the science cache; recordings are pre-synthesized under out/missions."""
    h, w = data.out_hw
    missions = [str(out / "missions" / f"synth-{s}-s{seed}")
                for seed in data.synth_seeds for s in SCENES]
    return parse_config({
        "output_dir": str(out / "run"),
        "synth": {"scenes": list(SCENES), "seconds": data.seconds, "cameras": ["front"],
                  "image_width": 3 * w, "image_height": 3 * h,
                  "points_per_sweep": data.points_per_sweep, "depth_maps": False},
        "ingest": {"cameras": ["front"], "out_height": h, "out_width": w,
                   "recordings": missions},
        "encoders": {"image_channels": data.image_channels,
                     "point_channels": data.point_channels},
        "cache": {"shard_views": 32}, "dag": {"executor": "local", "retries": 0},
        "clips": {"gap_max": data.gap_max, "eval_fraction": data.eval_fraction,
                  "eval_clips_per_recording": data.eval_clips_per_recording}})


def synthesize_missions(cfg: M3GDConfig, data: ScienceData) -> None:
    """Write every (scene, synth seed) mission named in cfg.ingest.recordings (skip existing)."""
    from pipeline.synth.api import synthesize

    for seed in data.synth_seeds:
        for scene in SCENES:
            name = f"synth-{scene}-s{seed}"
            where = Path(cfg.ingest.recordings[0]).parent
            if (where / f"{name}.done").exists():
                continue
            synthesize(where, cfg.synth.model_copy(update={"seed": seed}), scene, mission=name)
            (where / f"{name}.done").write_text("")


def build_science_cache(out: Path, data: ScienceData) -> Path:
    """Synthesize the missions and run every stage; returns the pipeline output directory."""
    from pipeline.bench.loader_bench import build_cache

    cfg = science_config(out, data)
    synthesize_missions(cfg, data)
    return build_cache(cfg)


@dataclass(frozen=True)
class ScienceSpec:
    """Model, optimization and evaluation settings of one science run."""

    steps: int = 1500
    batch_size: int = 8
    lr: float = 1e-3
    warmup_steps: int = 100
    lr_min: float = 1e-5
    width: int = 128
    depth: int = 4
    patch: int = 1
    prediction: str = "x"
    t_sampling: str = "uniform"
    t_mu: float = 0.0
    t_sigma: float = 1.0
    point_hidden: int = 256
    val_recordings: int = 2
    val_clips: int = 64
    val_every: int = 100
    eval_clips: int = 96
    guidance: float = 1.0
    threads: int = 1


def restrict(stream: ClipStream, recordings: set[str], keep: bool) -> ClipStream:
    """`stream` with only the clips of `recordings` (keep) or of all others (not keep)."""
    stream.clips = [c for c in stream.clips if (c["recording"] in recordings) == keep]
    if not stream.clips:
        raise ValueError(f"{stream.cache}: no clip left after the validation split")
    return stream


def val_recordings(output_dir: Path, n: int) -> set[str]:
    """`n` training recordings held out for validation (fixed for every run of the bench)."""
    names = sorted({c["recording"] for c in load_clips(output_dir, "train")})
    if n >= len(names):
        raise ValueError(f"{output_dir}: {len(names)} training recordings, cannot hold out {n}")
    rng = np.random.default_rng(12345)
    return {names[i] for i in rng.choice(len(names), n, replace=False)}


def fixed_batches(stream: ClipStream, clips: int, batch_size: int) -> list[dict[str, Tensor]]:
    """The model batches of the first `clips` clips of an unshuffled stream (read once)."""
    return [model_batch(b) for b in eval_batches(stream, batch_size, clips)]


def net_config(stream: ClipStream, mode: str, spec: ScienceSpec) -> NetConfig:
    """The network of `spec` sized from the cache behind `stream`."""
    base = net_config_from_cache(stream, mode, "tiny")
    return replace(base, patch=spec.patch, width=spec.width, depth=spec.depth,
                   prediction=spec.prediction, adapter_hidden=spec.point_hidden)


def train_config(spec: ScienceSpec, seed: int) -> TrainConfig:
    """Warm-up then cosine decay over the run; t sampling of `spec`."""
    return TrainConfig(lr=spec.lr, warmup_steps=spec.warmup_steps,
                       decay_steps=spec.steps - spec.warmup_steps, lr_min=spec.lr_min,
                       t_sampling=spec.t_sampling, t_mu=spec.t_mu, t_sigma=spec.t_sigma,
                       ema_decay=0.998, seed=seed)


@dataclass
class TrainedRun:
    """A trained network (best validation weights) and its curves."""

    net: M3GDNet
    losses: list[float]
    val_curve: list[dict[str, float]]
    best_step: int
    best_weights: str
    val_loss: float
    train_minutes: float


def train_run(output_dir: Path, mode: str, seed: int, spec: ScienceSpec) -> TrainedRun:
    """Train `mode` with `seed` on the training recordings minus the validation ones.

    Every `val_every` steps the fixed-noise t-grid loss of the validation batches is measured;
    the weights with the lowest one (raw at any check, or the EMA at the end) are kept.
    """
    held = val_recordings(output_dir, spec.val_recordings)
    stream = restrict(ClipStream(output_dir, "train", mode, seed=seed), held, keep=False)
    val = fixed_batches(restrict(ClipStream(output_dir, "train", mode, shuffle=False), held,
                                 keep=True), spec.val_clips, spec.batch_size)
    trainer = Trainer(net_config(stream, mode, spec), train_config(spec, seed))
    curve: list[dict[str, float]] = []
    best: dict[str, Any] = {"loss": math.inf}

    def check(step: int, _loss: float) -> None:
        if step % spec.val_every and step != spec.steps:
            return
        vl = float(t_binned_loss(trainer.net.eval(), val)["mean"])  # type: ignore[arg-type]
        curve.append({"step": step, "val_loss": vl})
        if vl < best["loss"]:
            best.update(loss=vl, step=step, weights="raw",
                        state=copy.deepcopy(trainer.net.state_dict()))

    t0 = time.perf_counter()
    losses = train_loop(trainer, stream, spec.steps, spec.batch_size, on_step=check)
    minutes = (time.perf_counter() - t0) / 60
    ema_loss = float(t_binned_loss(trainer.ema, val)["mean"])  # type: ignore[arg-type]
    net = trainer.net
    if ema_loss < best["loss"]:
        best.update(loss=ema_loss, step=spec.steps, weights="ema")
        net = trainer.ema
    else:
        net.load_state_dict(best["state"])
    return TrainedRun(net.eval(), losses, curve, int(best["step"]), str(best["weights"]),
                      float(best["loss"]), minutes)


def score(net: M3GDNet, output_dir: Path, mode: str, spec: ScienceSpec, steps: int,
          guidance: float, tol: float | None = None, split: str = "eval") -> dict[str, Any]:
    """`summarize` of `net` on the first spec.eval_clips clips of `split` (baselines beside)."""
    stream = ClipStream(output_dir, split, mode, shuffle=False, with_images=True)
    if split == "train":
        stream = restrict(stream, val_recordings(output_dir, spec.val_recordings), keep=True)
    decoder = image_decoder(stream, 0)
    t0 = time.perf_counter()
    results = score_clips(net, stream, decoder, spec.eval_clips, spec.batch_size, steps,
                          guidance, tol, 0)
    out = summarize(results, stream)
    out["seconds_per_target"] = (time.perf_counter() - t0) / out["targets"]
    return out
