"""Sampler benchmark (paper Table 7): latency, latency per target and peak memory against
Euler steps K and target views M; quality against K; adaptive stopping against fixed K.

One query = `sources` source views + M target views at the paper's dimensions (C = 1536,
C_u = 1224, 16 x 24 grid) by default. Latency is the median wall time of `sample()` over
`repeats` runs (the adapter, condition and K guided steps). Peak memory is the process RSS
high-water mark above the RSS just before the call, sampled every millisecond by a thread
(CPU torch has no allocator peak counter), so it is a lower bound at millisecond resolution.

Quality against K: without ground truth here, each K is scored by its relative L2 distance,
on target views, to a `reference_steps` solution from the same noise (how far the K-step
solve is from the converged ODE solution). Given a checkpoint the EMA weights are used;
without one, the tiny network is given deterministic random weights, so latency and memory
are representative but the quality columns only describe that random field.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch

from bench.measure import PeakRSS
from model.device import resolve_device, synchronize, to_device
from model.net import M3GDNet, NetConfig
from model.sampler import sample
from model.scoring import load_net
from schemas.config import M3GDConfig


@dataclass(frozen=True)
class SamplerBenchSpec:
    """Sizes and sweep of the sampler benchmark."""

    steps: tuple[int, ...] = (1, 5, 10, 20)
    targets: tuple[int, ...] = (2, 3, 4)
    sources: int = 2
    c: int = 1536
    c_u: int = 1224
    grid_hw: tuple[int, int] = (16, 24)
    image_hw: tuple[int, int] = (224, 336)
    preset: str = "tiny"
    guidance: float = 1.5
    repeats: int = 2
    reference_steps: int = 50
    tol: float = 1e-2
    seed: int = 0
    device: str = "cpu"  # model.device string; "cuda" times on the GPU (not run here)


def sampler_spec(quick: bool, net: dict[str, Any] | None, repeats: int | None,
                 device: str = "cpu") -> SamplerBenchSpec:
    """The bench's spec: the quick grid at small sizes (tests) or the full one; a
    checkpoint's sizes (its state's "net") when given; `repeats` timed runs per cell."""
    spec = SamplerBenchSpec(device=device)
    if quick:
        spec = replace(spec, steps=(1, 2), targets=(2,), c=16, c_u=8, grid_hw=(4, 6),
                       image_hw=(56, 84), repeats=1, reference_steps=4)
    if net is not None:
        spec = replace(spec, c=int(net["c"]), c_u=int(net["c_u"]),
                       grid_hw=(int(net["grid_hw"][0]), int(net["grid_hw"][1])),
                       image_hw=(int(net["image_hw"][0]), int(net["image_hw"][1])),
                       preset=str(net["preset"]))
    return spec if repeats is None else replace(spec, repeats=repeats)


def query_batch(spec: SamplerBenchSpec, n_targets: int, seed: int) -> dict[str, torch.Tensor]:
    """One random query (B = 1): sources then targets, cameras on a 0.5 m forward track."""
    gen = torch.Generator().manual_seed(seed)
    V, (gh, gw), (h, w) = spec.sources + n_targets, spec.grid_hw, spec.image_hw
    K = torch.tensor([[0.9 * w, 0.0, (w - 1) / 2], [0.0, 0.9 * w, (h - 1) / 2], [0.0, 0.0, 1.0]])
    T = torch.eye(4, dtype=torch.float64).repeat(1, V, 1, 1)
    T[0, :, 2, 3] = 0.5 * torch.arange(V, dtype=torch.float64)
    is_target = torch.zeros(1, V, dtype=torch.bool)
    is_target[0, spec.sources:] = True
    return {"latents": torch.randn(1, V, spec.c, gh, gw, generator=gen),
            "g": torch.rand(1, V, 6, gh, gw, generator=gen),
            "h": torch.randn(1, V, gh, gw, spec.c_u, generator=gen),  # channels-last
            "K": K.expand(1, V, 3, 3).clone(), "T_world_cam": T, "is_target": is_target}


def bench_net(spec: SamplerBenchSpec, checkpoint: Path | None, ema: bool = True) -> M3GDNet:
    """A checkpoint's EMA (or raw) network, or a deterministic random-weight one of `spec`."""
    if checkpoint is not None:
        return load_net(checkpoint, ema)[0]
    torch.manual_seed(spec.seed)
    net = M3GDNet(NetConfig(c=spec.c, c_u=spec.c_u, grid_hw=spec.grid_hw,
                            image_hw=spec.image_hw, preset=spec.preset)).eval()
    gen = torch.Generator().manual_seed(spec.seed)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.02 * torch.randn(p.shape, generator=gen))
    return net


def _weights_name(checkpoint: Path | None, ema: bool) -> str:
    """How the timed network's weights were obtained, for tables and JSON."""
    if checkpoint is None:
        return "random (untrained)"
    return "checkpoint EMA" if ema else "checkpoint raw"


def _rel_l2(a: torch.Tensor, b: torch.Tensor, is_target: torch.Tensor) -> float:
    """||a - b|| / ||b|| over target views."""
    return float((a[is_target] - b[is_target]).norm() / b[is_target].norm())


def _timed(net: M3GDNet, batch: dict[str, torch.Tensor], steps: int, spec: SamplerBenchSpec,
           tol: float | None = None) -> tuple[float, int, torch.Tensor, int]:
    """(median seconds, peak RSS bytes, z_0, steps taken) of `repeats` identical samples."""
    times, peak, res = [], 0, None
    for _ in range(spec.repeats):
        gen = torch.Generator().manual_seed(spec.seed)
        with PeakRSS() as mem:
            t0 = time.perf_counter()
            res = sample(net, batch, steps, spec.guidance, gen, tol)
            synchronize(res.z_0.device)
            times.append(time.perf_counter() - t0)
        peak = max(peak, mem.peak)
    assert res is not None
    return statistics.median(times), peak, res.z_0, res.steps


def run_sampler_bench(spec: SamplerBenchSpec, checkpoint: Path | None = None,
                      ema: bool = True) -> dict[str, Any]:
    """Latency table keyed by K then M, quality against K, adaptive against fixed K.

    With a checkpoint, its EMA weights (`ema`) or its raw ones are timed and scored.
    """
    device = resolve_device(spec.device)
    net = bench_net(spec, checkpoint, ema).to(device)
    latency: dict[str, dict[str, dict[str, float]]] = {}
    quality: dict[str, dict[str, float]] = {}
    adaptive: dict[str, dict[str, float]] = {}
    for M in spec.targets:
        batch = to_device(query_batch(spec, M, spec.seed + M), device)
        tgt = batch["is_target"]
        _, _, ref, _ = _timed(net, batch, spec.reference_steps, spec)
        for K in spec.steps:
            sec, peak, z, _ = _timed(net, batch, K, spec)
            latency.setdefault(str(K), {})[str(M)] = {
                "latency_s": sec, "latency_per_target_s": sec / M, "peak_mem_mb": peak / 2**20}
            quality.setdefault(str(K), {})[str(M)] = _rel_l2(z, ref, tgt)
        k_max = max(spec.steps)
        sec, _, z, taken = _timed(net, batch, k_max, spec, tol=spec.tol)
        adaptive[str(M)] = {"max_steps": k_max, "steps_taken": taken, "latency_s": sec,
                            "fixed_latency_s": latency[str(k_max)][str(M)]["latency_s"],
                            "rel_l2_to_reference": _rel_l2(z, ref, tgt),
                            "fixed_rel_l2_to_reference": quality[str(k_max)][str(M)]}
    return {"latency": latency, "quality_rel_l2_to_reference": quality, "adaptive": adaptive,
            "weights": _weights_name(checkpoint, ema),
            "spec": asdict(spec)}


def run_sampler_with_quality(cfg: M3GDConfig, quick: bool, checkpoint: Path | None,
                             clips: int, repeats: int | None, ema: bool,
                             device: torch.device) -> dict[str, Any]:
    """`run_sampler_bench` on the spec of `sampler_spec`; with a checkpoint also PSNR/SSIM of
    the first `clips` eval clips against K. Every figure uses the `ema` choice of a
    checkpoint's weights (raw by default, as `m3gd eval` does: EMA 0.9995 barely moves in a
    short run)."""
    from model.runs import ScoreRequest, checkpoint_meta, score_checkpoint
    from model.scoring import summarize

    net = checkpoint_meta(checkpoint)["net"] if checkpoint is not None else None
    spec = sampler_spec(quick, net, repeats, str(device))
    result = run_sampler_bench(spec, checkpoint, ema)
    if checkpoint is not None:
        quality: dict[str, Any] = {}
        for k in spec.steps:
            req = ScoreRequest(clips, k, spec.guidance, None, ema, keep_images=False)
            res, stream, _ = score_checkpoint(cfg, checkpoint, req, device)
            quality[str(k)] = summarize(res, stream)
        result["quality_psnr_ssim"] = quality
        result["quality_psnr_ssim_weights"] = "ema" if ema else "raw"
    return result
