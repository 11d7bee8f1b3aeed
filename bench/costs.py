"""Per-item costs of every stage, measured on this machine by running the real code.

`measure_item_costs` times, each as the fastest of `repeats` runs (noise on a shared machine
only adds time), one item of:

- ingest, per image: rosbags deserialization of a `sensor_msgs/CompressedImage` holding a
  GrandTour-sized (1920x1280) JPEG of a synthetic textured image, then `Rectifier.apply`
  (JPEG decode at the reduction it chooses + one remap to 224x336), `pipeline.ingest.calib.camera`;
- the packets stage's sweep decoding: rosbags deserialization of a Hesai-layout PointCloud2
  (point_step 26, unaligned float64 stamp) of a synthetic 64k-point sweep, then `decode_cloud`;
- select, per view: `pipeline.select.views._select_camera` (nearest sweep, two odometry
  interpolations, the LiDAR-to-camera chain, the Arrow rows) over a batch of views;
- encode, per image: the embedded `patch` encoder and `da3` (DA3-Base, random init: same
  architecture and arithmetic as the pretrained network, so the same cost);
- the point encoder `fpfh` per sweep at C_u channels;
- packets, per view: support sets, [g; h] with `packets.assemble`, float16 clip and cast, as in
  `pipeline.stages.packets`;
- cache writes: `bench.cache_bench.run_cache_bench` at a small size, with the packet
  occupancy measured above; bytes per view come from `schemas.cache_layout`.

Utonia cannot be installed here, so it is not measured (see `bench.scaling`).
Every figure is float seconds per item or bytes per item; keys are listed in `COST_KEYS`.
The load average during the run is recorded: on this shared 2-core machine other jobs inflate
wall times, so the CPU seconds of this process are reported beside them. `measure_in_worker`
runs the measurement in a fresh interpreter with one BLAS/OpenMP thread, as a DAG worker has.
The per-stage timers live in `bench.costs_stages`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import torch

from bench.costs_stages import (
    cache_costs,
    encoder_costs,
    image_costs,
    packet_cost,
    select_cost,
    sweep_costs,
    view_bytes,
)
from packets.assemble import SweepFeatures

_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
TIMED = ("ingest_image", "decode_sweep", "select_view", "encode_patch_image",
         "encode_da3_image", "encode_fpfh_sweep", "packet_view")
COST_KEYS = (
    *(f"{k}{s}" for k in TIMED for s in ("_s", "_wall_s")),
    "jpeg_bytes", "jpeg_reduction", "sweep_bytes", "cache_write_bytes_s", "occupancy",
    "packet_bytes_ratio", "image_bytes_view", "latent_bytes_view", "packet_raw_bytes_view",
    "meta_bytes_view", "n_points", "point_channels", "torch_threads", "blas_threads_env",
    "load_avg_1min",
)
"""Keys of `measure_item_costs` ('encode_da3_image_*' only with da3=True). For each timed
stage, `<stage>_s` is process CPU seconds per item (one dedicated core) and `<stage>_wall_s`
wall seconds per item; both the fastest of the repeats."""


def measure_item_costs(*, n_points: int = 64_000, point_channels: int = 1224,
                       image_channels: int = 1536, raw_hw: tuple[int, int] = (1280, 1920),
                       out_hw: tuple[int, int] = (224, 336), repeats: int = 3,
                       da3: bool = True, select_views: int = 600, cache_views: int = 64,
                       threads: int = 1, seed: int = 0,
                       workdir: Path | None = None) -> dict[str, float]:
    """Measure every stage's per-item cost here: float seconds or bytes per item (`COST_KEYS`).

    threads: torch threads (one per Dask worker in the DAG). da3=False skips building DA3-Base
    (then 'encode_da3_image_s' is absent). image_channels: C of the stored latents (the
    DA3-Base level 0 has 1536).
    """
    torch.set_num_threads(threads)
    load = os.getloadavg()[0]
    costs, rgb = image_costs(raw_hw, out_hw, repeats, seed)
    sweep, xyz = sweep_costs(n_points, repeats, seed)
    costs.update(sweep)
    costs.update(select_cost(select_views, repeats))
    enc_costs, feat = encoder_costs(rgb, xyz, point_channels, da3, repeats, seed)
    costs.update(enc_costs)
    costs.update(packet_cost(xyz, SweepFeatures.from_array(feat), out_hw, repeats))
    costs.update(view_bytes(out_hw, image_channels, point_channels))
    costs.update(cache_costs(out_hw, image_channels, point_channels, costs["occupancy"],
                             cache_views, workdir))
    costs["point_channels"] = float(point_channels)
    costs["torch_threads"] = float(torch.get_num_threads())
    env = next((os.environ[v] for v in _THREAD_VARS if os.environ.get(v)), "0")
    costs["blas_threads_env"] = float(env)  # 0: the BLAS library's default (all cores)
    costs["load_avg_1min"] = max(load, os.getloadavg()[0])
    return costs


def measure_in_worker(timeout_s: float = 1800.0, **kwargs: Any) -> dict[str, float]:
    """`measure_item_costs(**kwargs)` in a fresh interpreter configured like a DAG worker.

    OMP/MKL/OpenBLAS thread variables are set to 1 before numpy loads (as the LocalCluster
    workers of `pipeline.run.executors` get them) and torch uses one thread. kwargs must be
    JSON-serializable (tuples become lists and are turned back); RuntimeError on failure.
    """
    env = dict(os.environ)
    env.update(dict.fromkeys(_THREAD_VARS, "1"))
    cmd = [sys.executable, "-m", "bench.costs", json.dumps(kwargs)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout_s,
                          check=False)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"cost worker {kwargs} failed ({proc.returncode}): "
                           f"{proc.stderr.strip()[-2000:]}")
    out: dict[str, float] = json.loads(lines[-1])
    return out


def _main(argv: list[str]) -> None:
    """Print `measure_item_costs(**json.loads(argv[0]))` (no argument: defaults) as JSON."""
    kwargs = json.loads(argv[0]) if argv else {}
    for key in ("raw_hw", "out_hw"):
        if key in kwargs:
            kwargs[key] = tuple(kwargs[key])
    if "workdir" in kwargs:
        kwargs["workdir"] = Path(kwargs["workdir"])
    print(json.dumps(measure_item_costs(**kwargs)))


if __name__ == "__main__":
    _main(sys.argv[1:])
