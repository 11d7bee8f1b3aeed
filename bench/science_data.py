"""The synthetic data set of the science bench: which recordings (every scene at several synth
seeds), how they are synthesized, and the cache the real pipeline builds from them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from schemas.config import M3GDConfig, parse_config

if TYPE_CHECKING:
    from pipeline.run.stage import Stage

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
    gap_min: int = 1
    gap_max: int = 6
    eval_fraction: float = 0.25
    eval_clips_per_recording: int = 24
    train_clock_offset_s: float = 0.0  # camera clock minus LiDAR clock of training recordings


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
        "clips": {"gap_min": data.gap_min, "gap_max": data.gap_max,
                  "eval_fraction": data.eval_fraction,
                  "eval_clips_per_recording": data.eval_clips_per_recording}})


def synthesize_missions(cfg: M3GDConfig, data: ScienceData) -> None:
    """Write every (scene, synth seed) mission named in cfg.ingest.recordings (skip existing).

    With data.train_clock_offset_s, the recordings the clips stage will put in the training
    split get that camera clock offset, uncorrected (select.time_offset_s stays 0): their
    packets pair each image with the sweep of a shifted time; the eval recordings keep 0.
    """
    from model.clips import split_recordings
    from pipeline.synth.api import synthesize

    split = split_recordings([Path(r).name for r in cfg.ingest.recordings],
                             cfg.clips.eval_fraction, cfg.clips.seed)
    for seed in data.synth_seeds:
        for scene in SCENES:
            name = f"synth-{scene}-s{seed}"
            where = Path(cfg.ingest.recordings[0]).parent
            if (where / f"{name}.done").exists():
                continue
            offset = data.train_clock_offset_s if split.get(name) == "train" else 0.0
            synth = cfg.synth.model_copy(update={"seed": seed, "camera_clock_offset_s": offset})
            synthesize(where, synth, scene, mission=name)
            (where / f"{name}.done").write_text("")


def build_science_cache(out: Path, data: ScienceData, stages: Sequence[Stage]) -> Path:
    """Synthesize the missions and run the graph `stages` (dags.graph.STAGES, handed in by
    the command); returns the pipeline output directory."""
    from bench.loader_bench import build_cache

    cfg = science_config(out, data)
    synthesize_missions(cfg, data)
    return build_cache(cfg, stages)
