"""Cost and coverage of merging a second LiDAR into the packets (`select.lidar: [a, b]`).

`python -m bench.lidar_merge [--seconds S] [--repeats R] [--mode geom_only|full]`: one
synthetic recording with a second LiDAR (`synth.second_lidar`), run through ingest, select and
packets with the first LiDAR alone, the second alone and both merged, alternated `R` times in
fresh output folders; prints the packets stage's seconds (the fastest of the repeats), their
ratio to the first LiDAR alone measured in the same run, and the occupied cells per view.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from schemas.channels import VALIDITY, channel_index
from schemas.config import M3GDConfig, SynthConfig, parse_config

LIDARS = {"hesai": {"topic": "/boxi/hesai/points_undistorted", "frame": "hesai_lidar"},
          "livox": {"topic": "/livox/lidar", "frame": "livox_frame"}}
RUNS: dict[str, Any] = {"hesai": "hesai", "livox": "livox", "merged": ["hesai", "livox"]}


def _config(out: Path, mission: Path, lidar: Any, mode: str) -> M3GDConfig:
    return parse_config({
        "output_dir": str(out),
        "ingest": {"recordings": [str(mission)], "out_height": 224, "out_width": 336,
                   "topics": {"lidars": LIDARS}},
        "encoders": {"point_channels": 16},
        "select": {"lidar": lidar}, "packets": {"mode": mode}, "dag": {"executor": "local"}})


def _occupied(cfg: M3GDConfig, recording: str) -> float:
    """Mean occupied cells per valid view over the recording's camera groups."""
    root = zarr.open_group(str(cfg.layout.cache / recording), mode="r")
    counts = []
    for cam in root.group_keys():
        group = root[cam]
        assert isinstance(group, zarr.Group), cam
        g, valid = group["g"][:], group["valid"][:]  # type: ignore[index]
        counts.append((np.asarray(g)[np.asarray(valid), channel_index(VALIDITY)] > 0)
                      .sum(axis=(1, 2)))
    return float(np.concatenate(counts).mean())


def run(seconds: float, repeats: int, mode: str) -> dict[str, Any]:
    """Figures of the module doc, as a dict."""
    from dags.graph import STAGES
    from pipeline.run.service import run_stages
    from pipeline.synth.api import synthesize

    stages = [s for s in STAGES if s.name in ("synth", "ingest", "select", "packets")]
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        synthesize(base / "rec", SynthConfig(seconds=seconds, second_lidar=True,
                                             depth_maps=False), "corridor", mission="m")
        best: dict[str, float] = {}
        cells: dict[str, float] = {}
        for r in range(repeats):
            for name, lidar in RUNS.items():
                cfg = _config(base / f"{name}{r}", base / "rec" / "m", lidar, mode)
                out = run_stages(cfg, stages)
                if any(s.failed for s in out.summaries):
                    raise RuntimeError(f"run {name} failed: {out.summaries}")
                sec = next(s.seconds for s in out.summaries if s.name == "packets")
                best[name] = min(best.get(name, float("inf")), sec)
                cells[name] = _occupied(cfg, "m")
    return {"mode": mode, "seconds": seconds, "repeats": repeats,
            "packets_s": best, "packets_over_first": {k: v / best["hesai"]
                                                      for k, v in best.items()},
            "occupied_cells_per_view": cells}


def main() -> None:
    """Parse arguments, run, print JSON."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--mode", default="full", choices=("full", "geom_only"))
    a = ap.parse_args()
    print(json.dumps(run(a.seconds, a.repeats, a.mode), indent=1))


if __name__ == "__main__":
    main()
