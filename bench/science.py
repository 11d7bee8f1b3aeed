"""Science benchmark (issue 14): does the trained model beat trivial baselines, what does
LiDAR add, and what does sampling speed cost in quality.

One command (`m3gd bench science --json`) builds a synthetic cache through the real pipeline
(many short recordings: every scene at several synth seeds, so the model sees variety),
trains one model per (packet mode, seed), and scores held-out targets beside the
copy-nearest-source and dataset-mean-latent baselines on the same targets.
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

from bench.science_data import ScienceData, build_science_cache
from bench.science_report import aggregate
from model.compare import net_config_from_cache
from model.dataset import ClipStream, load_clips
from model.device import to_device
from model.evaluate import TargetResult
from model.loop import model_batch, train_loop
from model.net import M3GDNet, NetConfig
from model.scoring import eval_batches, image_decoder, mean_images, score_clips, summarize
from model.train_step import TrainConfig, Trainer
from model.validation import t_binned_loss
from pipeline.analysis.plots_science import plot_science
from schemas.modes import MODEL_MODES as MODES

if TYPE_CHECKING:
    from pipeline.run.stage import Stage

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
    anchor: str = "none"  # NetConfig.anchor
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
    device: str = "cpu"  # where the runs train and score (a torch device string)


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


def fixed_batches(stream: ClipStream, clips: int, batch_size: int,
                  device: str = "cpu") -> list[dict[str, Tensor]]:
    """The model batches of the first `clips` clips of an unshuffled stream (read once), on
    `device`."""
    dev = torch.device(device)
    return [to_device(model_batch(b), dev) for b in eval_batches(stream, batch_size, clips)]


def net_config(stream: ClipStream, mode: str, spec: ScienceSpec) -> NetConfig:
    """The network of `spec` sized from the cache behind `stream`."""
    base = net_config_from_cache(stream, mode, "tiny")
    return replace(base, patch=spec.patch, width=spec.width, depth=spec.depth,
                   prediction=spec.prediction, anchor=spec.anchor,
                   adapter_hidden=spec.point_hidden)


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


def train_run(output_dir: Path, mode: str, seed: int, spec: ScienceSpec,
              net_over: dict[str, Any] | None = None, train_over: dict[str, Any] | None = None,
              init: M3GDNet | None = None) -> TrainedRun:
    """Train `mode` with `seed` on the training recordings minus the validation ones.

    Every `val_every` steps the fixed-noise t-grid loss of the validation batches is measured;
    the weights with the lowest one (raw at any check, or the EMA at the end) are kept.
    net_over / train_over: NetConfig / TrainConfig fields set on top of `spec`'s (the paper
    suite's variants); init: a no_lidar network a freeze or finetune run starts from.
    """
    held = val_recordings(output_dir, spec.val_recordings)
    stream = restrict(ClipStream(output_dir, "train", mode, seed=seed), held, keep=False)
    val = fixed_batches(restrict(ClipStream(output_dir, "train", mode, shuffle=False), held,
                                 keep=True), spec.val_clips, spec.batch_size, spec.device)
    cfg = replace(net_config(stream, mode, spec), **(net_over or {}))
    trainer = Trainer(cfg, replace(train_config(spec, seed), **(train_over or {})),
                      device=torch.device(spec.device))
    if init is not None:
        start_from_net(trainer, init)
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


def start_from_net(trainer: Trainer, source: M3GDNet) -> None:
    """Load a no_lidar network's weights into a trainer (net and EMA), packet inputs zero
    (`model.training_modes.adapted_state`)."""
    from model.training_modes import adapted_state

    new = adapted_state(source.state_dict(), trainer.net.state_dict(), trainer.net_cfg.c)
    trainer.net.load_state_dict(new)
    trainer.ema.load_state_dict(new)


@dataclass(frozen=True)
class TimedScores:
    """Per-target results of `timed_scores` and the CPU and wall seconds they took."""

    results: list[TargetResult]
    cpu_seconds: float
    wall_seconds: float

    def per_target(self) -> dict[str, float]:
        """CPU and wall seconds per target (`seconds_per_target`, `wall_seconds_per_target`)."""
        n = max(len(self.results), 1)
        return {"seconds_per_target": self.cpu_seconds / n,
                "wall_seconds_per_target": self.wall_seconds / n}


def timed_scores(net: M3GDNet, output_dir: Path, stream: ClipStream, spec: ScienceSpec,
                 steps: int, guidance: float, tol: float | None = None,
                 clips: int | None = None, keep_images: bool = True,
                 temperature: float = 1.0) -> TimedScores:
    """`score_clips` of `net` on the first `clips` (default spec.eval_clips) clips of `stream`
    (of the cache under `output_dir`; with_images, unshuffled) beside the baselines, the mean
    images built before the clock starts; CPU time (robust to neighbours) and wall time. The
    noise is seeded (0)."""
    decoder = image_decoder(stream, 0)
    trained = training_recordings(output_dir, spec)
    mean_images(stream, trained)  # memoized: built before the clock starts
    n = spec.eval_clips if clips is None else clips
    t0, w0 = time.process_time(), time.perf_counter()
    results = score_clips(net, stream, decoder, n, spec.batch_size, steps, guidance, tol, 0,
                          keep_images=keep_images, train_recordings=trained,
                          temperature=temperature)
    return TimedScores(results, time.process_time() - t0, time.perf_counter() - w0)


def score(net: M3GDNet, output_dir: Path, mode: str, spec: ScienceSpec, steps: int,
          guidance: float, tol: float | None = None, split: str = "eval",
          temperature: float = 1.0) -> dict[str, Any]:
    """`summarize` of `net` on the first spec.eval_clips clips of `split` (baselines beside);
    split "train" scores the validation recordings (`val_recordings`)."""
    stream = ClipStream(output_dir, split, mode, shuffle=False, with_images=True)
    if split == "train":
        stream = restrict(stream, val_recordings(output_dir, spec.val_recordings), keep=True)
    timed = timed_scores(net, output_dir, stream, spec, steps, guidance, tol,
                         temperature=temperature)
    return summarize(timed.results, stream) | timed.per_target()


def training_recordings(output_dir: Path, spec: ScienceSpec) -> set[str]:
    """The recordings the runs train on (the training split minus the validation ones):
    the training views of the mean-image baselines."""
    held = val_recordings(output_dir, spec.val_recordings)
    return {c["recording"] for c in load_clips(output_dir, "train")} - held


def eval_loss(net: M3GDNet, output_dir: Path, mode: str, spec: ScienceSpec) -> dict[str, Any]:
    """Fixed t-grid, fixed-noise flow-matching loss (`t_binned_loss`) on the first
    spec.eval_clips clips of the eval recordings: the held-out loss no choice was made on
    (the validation recordings pick the weights). Returns {"t", "loss" per t, "mean"}."""
    stream = ClipStream(output_dir, "eval", mode, shuffle=False)
    batches = fixed_batches(stream, spec.eval_clips, spec.batch_size, spec.device)
    return t_binned_loss(net, batches)


HEADLINE = ("psnr_model_k1", "psnr_model_k1_std", "psnr_model_k10", "psnr_model_k10_std",
            "psnr_copy_source", "psnr_mean_latent", "psnr_mean_image", "ssim_mean_image",
            "psnr_recording_mean_oracle", "psnr_reprojection", "ssim_reprojection",
            "reprojection_margin_db", "model_margin_reprojection_db", "strongest_baseline",
            "model_margin_db", "model_margin_db_k1", "strongest_ssim_baseline",
            "model_ssim_margin", "model_ssim_margin_k1",
            "val_loss_full", "val_loss_full_std", "val_loss_no_lidar", "val_loss_no_lidar_std",
            "eval_loss_full", "eval_loss_full_std", "eval_loss_no_lidar", "eval_loss_no_lidar_std",
            "lidar_effect_db", "lidar_effect_db_std", "lidar_effect_pairs",
            *(f"reproj_err_{m}_k{k}" for m in ("full", "no_lidar") for k in (1, 10)),
            "reproj_err_ground_truth", "reproj_err_copy_source", "reproj_err_mean_latent",
            "reproj_err_reprojection",
            "train_minutes",
            "wall_minutes", "plots")
"""Keys `m3gd bench science` prints (science.json holds everything)."""


def save_net(net: M3GDNet, where: Path) -> None:
    """The trained network's weights and config (safetensors + JSON) for the trade study."""
    from safetensors.torch import save_file

    where.mkdir(parents=True, exist_ok=True)
    save_file({k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()},
              str(where / "net.safetensors"))
    (where / "net.json").write_text(json.dumps(net.cfg.to_json()))


def load_net(where: Path, device: str = "cpu") -> M3GDNet:
    """Inverse of `save_net` (eval mode, on `device`)."""
    from safetensors.torch import load_file

    net = M3GDNet(NetConfig.from_json(json.loads((where / "net.json").read_text())))
    net.load_state_dict(load_file(str(where / "net.safetensors")))
    return net.to(torch.device(device)).eval()


def run_one(output_dir: Path, mode: str, seed: int, spec: ScienceSpec, ks: tuple[int, ...],
            save_to: Path | None) -> dict[str, Any]:
    """Train one (mode, seed) run and score its held-out targets at each K of `ks`."""
    torch.set_num_threads(spec.threads)
    run = train_run(output_dir, mode, seed, spec)
    if save_to is not None:
        save_net(run.net, save_to)
    out: dict[str, Any] = {"mode": mode, "seed": seed, "device": spec.device,
                           "train_minutes": run.train_minutes,
                           "best_step": run.best_step, "best_weights": run.best_weights,
                           "val_loss": run.val_loss, "val_curve": run.val_curve,
                           "train_loss": run.losses}
    out["eval_loss"] = eval_loss(run.net, output_dir, mode, spec)
    for k in ks:
        out[f"eval_k{k}"] = score(run.net, output_dir, mode, spec, k, spec.guidance)
    return out


def _run_file(workdir: Path, mode: str, seed: int) -> Path:
    return workdir / "runs" / f"{mode}-s{seed}.json"


def _one_job(args: tuple[Path, str, int, ScienceSpec, tuple[int, ...], Path]) -> Path:
    """Pool worker: one run, its JSON written atomically (a rerun skips finished runs); the
    trained network is kept under workdir/nets/<mode>-s<seed> for later study."""
    from schemas.atomic_io import write_text_atomic

    output_dir, mode, seed, spec, ks, workdir = args
    res = run_one(output_dir, mode, seed, spec, ks, workdir / "nets" / f"{mode}-s{seed}")
    return write_text_atomic(_run_file(workdir, mode, seed), json.dumps(res))


def run_study(output_dir: Path, spec: ScienceSpec, workdir: Path,
              modes: tuple[str, ...] = MODES, seeds: tuple[int, ...] = (0, 1, 2),
              ks: tuple[int, ...] = (1, 10), jobs: int = 1,
              train_missing: bool = True) -> list[dict[str, Any]]:
    """Every (mode, seed) run, `jobs` at a time in spawned processes; finished runs (their
    JSON under workdir/runs) are not repeated. Returns the per-run results that exist
    (with train_missing False, only those already finished: a study cut short by time)."""
    from bench.worker_pool import spawn_pool

    todo = [(output_dir, m, s, spec, ks, workdir) for s in seeds for m in modes
            if train_missing and not _run_file(workdir, m, s).exists()]
    if jobs > 1 and len(todo) > 1:
        with spawn_pool(jobs) as pool:  # workers end with this process
            list(pool.map(_one_job, todo))
    else:
        for job in todo:
            _one_job(job)
    return [json.loads(_run_file(workdir, m, s).read_text()) for s in seeds for m in modes
            if _run_file(workdir, m, s).exists()]


def speed_accuracy(net: M3GDNet, output_dir: Path, mode: str, spec: ScienceSpec,
                   ks: tuple[int, ...] = (1, 2, 5, 10, 20),
                   tols: tuple[float, ...] = (0.1, 0.03, 0.01),
                   guidances: tuple[float, ...] = (1.0, 1.5, 2.0)) -> list[dict[str, Any]]:
    """PSNR/SSIM against wall seconds per target for fixed K x guidance and for adaptive
    stopping (at most max(ks) steps) x guidance, on the first spec.eval_clips eval clips.

    Seconds per target are CPU seconds of this process (sampling, decoding and scoring, one
    torch thread): wall time on the shared 2-core machine measures the neighbours instead.
    """
    rows: list[dict[str, Any]] = []
    settings = [(k, None) for k in ks] + [(max(ks), tol) for tol in tols]
    for s in guidances:
        for k, tol in settings:
            r = score(net, output_dir, mode, spec, k, s, tol)
            rows.append({"sampler": f"K={k}" if tol is None else f"adaptive tol={tol:g}",
                         "K": k, "tol": tol, "guidance": s, "psnr": r["psnr_mean"],
                         "ssim": r["ssim_mean"], "seconds_per_target": r["seconds_per_target"],
                         "wall_seconds_per_target": r["wall_seconds_per_target"],
                         "targets": r["targets"],
                         **{f"{m}_{n}": v[f"{m}_mean"]
                            for n, v in r["baselines"].items() for m in ("psnr", "ssim")}})
    return rows


@dataclass(frozen=True)
class SciencePreset:
    """One full science bench: data, model/training, study size."""

    data: ScienceData
    spec: ScienceSpec
    seeds: tuple[int, ...] = (0, 1, 2)
    modes: tuple[str, ...] = MODES
    trade_clips: int = 24


FULL = SciencePreset(replace(ScienceData(), gap_min=4, gap_max=12),
                     ScienceSpec(steps=8000, warmup_steps=50, val_every=500, val_clips=32,
                                 eval_clips=48), trade_clips=16)
"""The documented configuration (docs/benchmarks_model.md, 'Science bench'): wide baselines
(4-12 frames between clip views, every clip over 1 m), 8000 steps, 4 modes x 3 seeds."""

NARROW = SciencePreset(ScienceData(), replace(FULL.spec, steps=2000, val_every=200),
                       modes=("full", "no_lidar"), trade_clips=16)
"""Narrow baselines (1-6 frames between views, the earlier preset), where copying the
nearest source view is the strong baseline: full vs no_lidar over 3 seeds, 2000 steps."""

QUICK = SciencePreset(
    ScienceData(synth_seeds=(0,), seconds=4.0, points_per_sweep=1024,
                eval_clips_per_recording=4),
    ScienceSpec(steps=30, warmup_steps=5, batch_size=4, width=64, depth=1, val_recordings=1,
                val_clips=4, val_every=15, eval_clips=4),
    seeds=(0,), modes=("full", "no_lidar"), trade_clips=2)
"""A few minutes: the same code path on a tiny cache (for tests; numbers mean nothing)."""


def _trade(output_dir: Path, preset: SciencePreset, workdir: Path) -> list[dict[str, Any]]:
    """The speed-accuracy rows of full seed 0 (workdir/trade.json is reused by a rerun)."""
    from schemas.atomic_io import write_text_atomic

    cached = workdir / "trade.json"
    if cached.exists():
        rows: list[dict[str, Any]] = json.loads(cached.read_text())
        return rows
    torch.set_num_threads(preset.spec.threads)  # as the runs: CPU and wall seconds of 1 thread
    net = load_net(workdir / "nets" / f"full-s{preset.seeds[0]}", preset.spec.device)
    trade_spec = replace(preset.spec, eval_clips=preset.trade_clips)
    rows = speed_accuracy(net, output_dir, "full", trade_spec)
    write_text_atomic(cached, json.dumps(rows))
    return rows


def run_science(preset: SciencePreset, workdir: Path, stages: Sequence[Stage],
                cache: Path | None = None, jobs: int = 1,
                train_missing: bool = True) -> dict[str, Any]:
    """Build (or reuse) the cache, train every (mode, seed), score K = 1 and 10 beside the
    baselines, aggregate over seeds, run the speed-accuracy trade on full seed 0, plot.

    workdir keeps the cache (workdir/data), per-run JSON (workdir/runs, reused by a rerun),
    every trained network (workdir/nets/<mode>-s<seed>), the plots and science.json.
    """
    from schemas.atomic_io import write_text_atomic

    t0 = time.perf_counter()
    output_dir = cache or build_science_cache(workdir / "data", preset.data, stages)
    runs = run_study(output_dir, preset.spec, workdir, preset.modes, preset.seeds,
                     jobs=jobs, train_missing=train_missing)
    result: dict[str, Any] = aggregate(runs)
    result["speed_accuracy"] = _trade(output_dir, preset, workdir)
    result |= {"runs": runs, "seeds": list(preset.seeds), "modes": list(preset.modes),
               "data": asdict(preset.data), "spec": asdict(preset.spec),
               "cache": str(output_dir), "wall_minutes": (time.perf_counter() - t0) / 60}
    result["plots"] = [str(p) for p in plot_science(result, workdir / "plots")]
    write_text_atomic(workdir / "science.json", json.dumps(result, indent=1))
    return result
