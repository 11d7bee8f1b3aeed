"""What the sampler's temperature buys and costs: accuracy against the spread of the draws.

`python -m bench.sampler_temperature WORKDIR --rows full_warp,warp_x` reads the networks a
paper suite kept (`WORKDIR/nets/<row>-s<seed>`, `m3gd bench science --suite paper-cpu`) and
its cache (`WORKDIR/paper.json`), samples the first eval clips twice (two noise seeds) at K
steps for each temperature, and prints per row and temperature, over the suite's seeds:

  psnr      mean PSNR (dB) of the first draw against the ground truth
  ssim      its mean SSIM
  spread    how far two draws of the same target lie apart: the RMS difference of the two
            decoded images over all pixels and channels, divided by sqrt(2) (the per-pixel
            standard deviation of a draw, in 8-bit levels); 0 is a deterministic sampler

and writes them to WORKDIR/temperature.json. PSNR rewards the conditional mean; the spread is
what a lower temperature gives up (`model.sampler.sample`).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from bench.science_tempered import TEMPERATURES
from model.scoring import score_clips

if TYPE_CHECKING:
    from collections.abc import Sequence

    from model.dataset import ClipStream
    from model.encoders.base import ImageDecoder
    from model.evaluate import TargetResult
    from model.net import M3GDNet


@dataclass(frozen=True)
class Draws:
    """How the eval targets are sampled: K steps, guidance s, the first `clips` clips in
    batches of `batch_size`, the two noise seeds."""

    steps: int = 10
    guidance: float = 1.0
    clips: int = 24
    batch_size: int = 8
    seeds: tuple[int, int] = (0, 1)


def draw_spread(a: Sequence[TargetResult], b: Sequence[TargetResult]) -> float:
    """Mean over targets of RMS(pred_a - pred_b) / sqrt(2) (8-bit levels): the per-pixel
    standard deviation of one draw, from two draws of the same targets (same order, images
    kept). A ValueError when the targets differ or an image is missing."""
    if len(a) != len(b) or not a:
        raise ValueError(f"two draws of the same targets needed, got {len(a)} and {len(b)}")
    out = []
    for x, y in zip(a, b, strict=True):
        if (x.clip_id, x.view) != (y.clip_id, y.view) or x.pred is None or y.pred is None:
            raise ValueError(f"target {x.clip_id}/{x.view}: not the same target, or no image")
        d = x.pred.astype(np.float64) - y.pred.astype(np.float64)
        out.append(math.sqrt(float(np.mean(d * d)) / 2))
    return statistics.fmean(out)


def temperature_rows(net: M3GDNet, stream: ClipStream, decoder: ImageDecoder, draws: Draws,
                     temperatures: Sequence[float] = TEMPERATURES) -> list[dict[str, float]]:
    """Per temperature: psnr and ssim of the first draw, spread of the two (`draw_spread`)."""
    rows = []
    for t in temperatures:
        a, b = (score_clips(net, stream, decoder, draws.clips, draws.batch_size, draws.steps,
                            draws.guidance, None, seed, image_baselines=False, temperature=t)
                for seed in draws.seeds)
        rows.append({"temperature": t, "psnr": statistics.fmean(r.psnr for r in a),
                     "ssim": statistics.fmean(r.ssim for r in a), "spread": draw_spread(a, b)})
    return rows


def mean_over_seeds(per_seed: list[list[dict[str, float]]]) -> list[dict[str, float]]:
    """The rows of several seeds (same temperatures, same order) as mean and std per key."""
    out = []
    for rows in zip(*per_seed, strict=True):
        row: dict[str, float] = {"temperature": rows[0]["temperature"]}
        for key in ("psnr", "ssim", "spread"):
            xs = [r[key] for r in rows]
            row[key] = statistics.fmean(xs)
            row[f"{key}_std"] = statistics.stdev(xs) if len(xs) > 1 else 0.0
        out.append(row)
    return out


def run(workdir: Path, rows: Sequence[str], draws: Draws) -> dict[str, Any]:
    """Every kept network of `rows` in a paper-suite workdir, at every temperature."""
    from bench.science import load_net
    from model.dataset import ClipStream
    from model.scoring import image_decoder

    torch.set_num_threads(1)
    paper = json.loads((workdir / "paper.json").read_text())
    cache = Path(paper["caches"]["clean"])
    out: dict[str, Any] = {"draws": asdict(draws), "rows": {}}
    for row in rows:
        nets = sorted((workdir / "nets").glob(f"{row}-s*"))
        if not nets:
            raise SystemExit(f"{workdir / 'nets'}: no network of row {row!r}")
        per_seed = []
        for where in nets:
            net = load_net(where)
            stream = ClipStream(cache, "eval", net.cfg.mode, shuffle=False, with_images=True)
            per_seed.append(temperature_rows(net, stream, image_decoder(stream, 0), draws))
        out["rows"][row] = {"seeds": [p.name for p in nets], "by_temperature":
                            mean_over_seeds(per_seed)}
    (workdir / "temperature.json").write_text(json.dumps(out, indent=1))
    return out


def main(argv: Sequence[str] | None = None) -> None:
    """Command line: print the table; WORKDIR/temperature.json."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("workdir", type=Path, help="a paper-suite workdir (paper.json, nets/)")
    p.add_argument("--rows", default="full_warp,warp_x", help="comma-separated rows")
    p.add_argument("--steps", type=int, default=10, help="Euler steps K")
    args = p.parse_args(argv)
    out = run(args.workdir, args.rows.split(","), Draws(steps=args.steps))
    print(f"K = {args.steps}; mean ± std over seeds; spread: 8-bit levels per pixel")
    print(f"{'row':<12} {'T':>5} {'PSNR dB':>14} {'SSIM':>14} {'spread':>14}")
    for row, r in out["rows"].items():
        for x in r["by_temperature"]:
            print(f"{row:<12} {x['temperature']:>5.2f} {x['psnr']:>8.2f} ± {x['psnr_std']:.2f}"
                  f" {x['ssim']:>8.3f} ± {x['ssim_std']:.3f}"
                  f" {x['spread']:>8.2f} ± {x['spread_std']:.2f}")


if __name__ == "__main__":
    main()
