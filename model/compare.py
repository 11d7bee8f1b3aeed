"""Science check: train one packet mode for a fixed budget, score target views on held-out clips.

Used to compare 'full' against 'no_lidar' (or any two modes of the paper's ablation) with the
same seed, data order, network preset and step budget. Scores are PSNR/SSIM of decoded target
views against the ground-truth images of the 'eval' split (recording-level split, no overlap).
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from model.dataset import ClipStream
from model.encoders.base import ImageDecoder
from model.loop import train_loop
from model.net import NetConfig
from model.scoring import score_clips, summarize
from model.train_step import TrainConfig, Trainer


@dataclass(frozen=True)
class CompareSpec:
    """Budget of one science-check run."""

    steps: int = 300
    batch_size: int = 4
    eval_clips: int = 64
    sample_steps: int = 10
    guidance: float = 1.5
    preset: str = "tiny"
    use_ema: bool = False  # EMA 0.9995 barely moves in a few hundred steps
    seed: int = 0


def net_config_from_cache(stream: ClipStream, mode: str, preset: str) -> NetConfig:
    """NetConfig matching the cache behind `stream` (C, C_u, grid, image size)."""
    where, attrs = stream.first_group()
    if attrs.image_encoder is None:
        raise ValueError(f"{where}: no image encoder identity in the attributes")
    c_u = attrs.point_encoder.channels if attrs.point_encoder is not None else 0
    grid = (attrs.image_h // attrs.patch, attrs.image_w // attrs.patch)
    return NetConfig(c=attrs.image_encoder.channels, c_u=c_u, grid_hw=grid,
                     image_hw=(attrs.image_h, attrs.image_w), mode=mode, preset=preset)


def train_and_score(output_dir: Path, mode: str, decoder: ImageDecoder, spec: CompareSpec,
                    train_cfg: TrainConfig | None = None,
                    net_cfg: NetConfig | None = None) -> dict[str, Any]:
    """Train `mode` for spec.steps on the 'train' split; PSNR/SSIM of eval-split targets.

    net_cfg defaults to `net_config_from_cache` with spec.preset.
    """
    stream = ClipStream(output_dir, "train", mode, seed=spec.seed)
    cfg = net_cfg or net_config_from_cache(stream, mode, spec.preset)
    trainer = Trainer(cfg, replace(train_cfg or TrainConfig(lr=1e-3), seed=spec.seed))
    losses = train_loop(trainer, stream, spec.steps, spec.batch_size)
    net = trainer.ema if spec.use_ema else trainer.net.eval()
    ev = ClipStream(output_dir, "eval", mode, seed=spec.seed, shuffle=False, with_images=True)
    results = score_clips(net, ev, decoder, spec.eval_clips, spec.batch_size, spec.sample_steps,
                          spec.guidance, None, spec.seed)
    summary = summarize(results, ev)
    return {"mode": mode, "steps": spec.steps, "final_loss": statistics.fmean(losses[-20:]),
            "eval_clips": summary["clips"], "eval_targets": summary["targets"],
            **{k: summary[k] for k in ("psnr_mean", "psnr_median", "ssim_mean", "baselines",
                                       "margin_db") if k in summary}}
