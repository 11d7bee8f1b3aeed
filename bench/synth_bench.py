"""Synthetic-recording benchmark: generation time against the raycasting floor, same run.

- `synth_wall_s` / `synth_cpu_s`: wall and process CPU time of `synthesize` (all threads; the
  CPU figure is the one to compare across loaded machines).
- `raycast_floor_wall_s`: casting the same rays (every image's pixels and every sweep's beams)
  through the same scene with one `cast_rays` call each, nothing else: no texture, no JPEG, no
  bags, no ground truth. `over_floor` = synth wall / floor wall (the price of everything else).
- `load_avg_1min`: the machine's load when the run started (other jobs share the CPU).

Run: `python -m bench.synth_bench [seconds] [scene]` (default: 20 s corridor at the
demo resolution); prints JSON.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.measure import fastest
from pipeline.synth.api import synthesize
from pipeline.synth.lidar import RINGS, LidarModel
from pipeline.synth.rig import build_rig
from pipeline.synth.scene import Raycaster, build_scene
from schemas.config import SynthConfig


def raycast_floor(cfg: SynthConfig, scene: str, n_images: int, n_sweeps: int) -> float:
    """Wall seconds to cast n_images camera ray sets and n_sweeps LiDAR ray sets, nothing else."""
    scn = build_scene(scene, cfg.seed, cfg.speed_mps * (cfg.seconds + 3.0))
    rc = Raycaster(scn)
    cam = build_rig(cfg.image_width, cfg.image_height, np.random.default_rng(0)).cameras["front"]
    rays = np.ascontiguousarray(cam.pixel_rays().reshape(-1, 3).T)
    beams = LidarModel.for_points(cfg.points_per_sweep, 0.0, 0.0, 1e3).ring_dirs()
    beams32 = beams.reshape(-1, 3).astype(np.float32)
    origin = np.array([0.0, 0.0, 1.0], dtype=np.float32)
    t0 = time.perf_counter()
    for _ in range(n_images):
        rc.cast_soa(origin, rays)
    for _ in range(n_sweeps):
        rc.cast(np.broadcast_to(origin, beams32.shape), beams32)
    return time.perf_counter() - t0


def run(seconds: float = 20.0, scene: str = "corridor", **overrides: Any) -> dict[str, Any]:
    """Generate one recording in a temp folder and time it against the raycasting floor."""
    cfg = SynthConfig(seconds=seconds, **overrides)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        wall, cpu, res = fastest(lambda: synthesize(Path(tmp), cfg, scene))
    n_images = sum(res.images.values())
    floor = raycast_floor(cfg, scene, n_images, res.sweeps)
    return {
        "scene": scene, "seconds": seconds,
        "image_size": [cfg.image_width, cfg.image_height],
        "points_per_sweep": (cfg.points_per_sweep // RINGS) * RINGS,
        "images": n_images, "sweeps": res.sweeps,
        "synth_wall_s": round(wall, 3), "synth_cpu_s": round(cpu, 3),
        "raycast_floor_wall_s": round(floor, 4), "over_floor": round(wall / floor, 2),
        "load_avg_1min": round(load, 2),
    }  # fmt: skip


def main() -> None:
    """Print the benchmark JSON (args: seconds, scene)."""
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 20.0
    scene = sys.argv[2] if len(sys.argv) > 2 else "corridor"
    print(json.dumps(run(seconds, scene), indent=1))


if __name__ == "__main__":
    main()
