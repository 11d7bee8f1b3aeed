"""One training update at the paper's sizes, measured on this machine.

Paper sizes: DA3 level-0 latents C = 1536 on a 16 x 24 grid (224 x 336 images), Utonia
descriptors C_u = 1224, 'full' packets, clips of V = 4 views (2 sources, 2 targets), the
'gld' preset (DiT-XL: width 1152, 28 blocks, 16 heads, patch 1: 4 x 384 = 1536 tokens).
The whole network's training state (weights, EMA, AdamW moments, gradients: about 16 bytes
per parameter) does not fit beside other work on a small CPU machine, so the update is
timed at a few depths and both time and memory are extended linearly to 28 blocks (every
block has the same size; the fit's residual is reported). Each depth runs in its own
process so its peak RSS is its own.
"""

from __future__ import annotations

import json
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

import torch

from model.net import NetConfig
from model.train_step import TrainConfig, Trainer
from model.transformer import PRESETS

PAPER_C, PAPER_C_U = 1536, 1224
PAPER_GRID_HW: tuple[int, int] = (16, 24)
PAPER_IMAGE_HW: tuple[int, int] = (224, 336)
PAPER = {"c": PAPER_C, "c_u": PAPER_C_U, "grid_hw": PAPER_GRID_HW, "image_hw": PAPER_IMAGE_HW}
VIEWS, SOURCES = 4, 2


def paper_batch(batch: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Random clips of the paper's sizes, packets with about half the cells occupied."""
    gen = torch.Generator().manual_seed(seed)
    gh, gw = PAPER_GRID_HW
    h, w = PAPER_IMAGE_HW
    K = torch.tensor([[0.9 * w, 0.0, (w - 1) / 2], [0.0, 0.9 * w, (h - 1) / 2], [0, 0, 1.0]])
    T = torch.eye(4, dtype=torch.float64).repeat(batch, VIEWS, 1, 1)
    T[:, :, 2, 3] = 0.5 * torch.arange(VIEWS, dtype=torch.float64)
    is_target = torch.zeros(batch, VIEWS, dtype=torch.bool)
    is_target[:, SOURCES:] = True
    g = torch.rand(batch, VIEWS, 6, gh, gw, generator=gen)
    n = int((g[:, :, 0] > 0.5).sum())
    return {"latents": torch.randn(batch, VIEWS, PAPER_C, gh, gw, generator=gen), "g": g,
            "h": torch.randn(n, PAPER_C_U, generator=gen).half(),
            "K": K.expand(batch, VIEWS, 3, 3).clone(), "T_world_cam": T, "is_target": is_target}


def measure_depth(depth: int, batch: int, steps: int, precision: str) -> dict[str, float]:
    """Seconds per update (median of `steps` after one warm-up) and peak RSS (GB) of this
    process for the gld preset cut to `depth` blocks."""
    torch.set_num_threads(1)
    cfg = NetConfig(**PAPER, mode="full", preset="gld", depth=depth)  # type: ignore[arg-type]
    tr = Trainer(cfg, TrainConfig(precision=precision))
    params = sum(p.numel() for p in tr.net.parameters())
    b = paper_batch(batch)
    tr.step(b)
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        tr.step(b)
        times.append(time.perf_counter() - t0)
    return {"depth": depth, "params": params, "seconds_per_update": statistics.median(times),
            "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6}


def _line(xs: Sequence[float], ys: Sequence[float], at: float) -> tuple[float, float]:
    """Least-squares line through (xs, ys) evaluated at `at`; the largest |residual|."""
    n = len(xs)
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx
    resid = max(abs(y - (my + slope * (x - mx))) for x, y in zip(xs, ys, strict=True))
    return my + slope * (at - mx), resid


def run_paper_step(depths: Sequence[int] = (1, 2, 3), batch: int = 1, steps: int = 2,
                   precision: str = "fp32") -> dict[str, Any]:
    """Every depth in its own process, then the linear extension to the preset's depth."""
    rows = []
    for d in depths:
        code = ("import json, sys; from bench.paper_step import measure_depth; "
                "print(json.dumps(measure_depth(*map(int, sys.argv[1:4]), sys.argv[4])))")
        out = subprocess.run([sys.executable, "-c", code, str(d), str(batch), str(steps),
                              precision], check=True, capture_output=True, text=True).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
    full = PRESETS["gld"].depth
    xs = [float(r["depth"]) for r in rows]
    sec, sec_res = _line(xs, [r["seconds_per_update"] for r in rows], full)
    rss, rss_res = _line(xs, [r["peak_rss_gb"] for r in rows], full)
    par, _ = _line(xs, [float(r["params"]) for r in rows], full)
    return {"batch": batch, "precision": precision, "threads": 1, "measured": rows,
            "depth": full, "params": par, "seconds_per_update": sec,
            "seconds_fit_residual": sec_res, "peak_rss_gb": rss, "rss_fit_residual_gb": rss_res}
