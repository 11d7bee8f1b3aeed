"""Peak memory of one packing worker: encode a 64k-point sweep with `fpfh` and pack 3 views.

Each configuration runs in a fresh Python subprocess (`python -m bench.packing_bench
--worker ...`), so the peak resident set size measured is that of one worker alone: the
kernel's high-water mark of the child's own address space (`VmHWM` of /proc/self/status,
reset by exec; `ru_maxrss` is reported beside it for reference, but on Linux it can carry over
the parent's peak through fork + exec). The worker:

1. builds the synthetic LiDAR-like sweep of `bench.packets_bench` (32 rings, ground,
   panels, a 40 m wall; float64 (N, 3) metres);
2. encodes it once with the embedded point encoder `fpfh` at C_u channels (float32 (N, C_u));
3. packs it into 3 views (224x336 pinhole, 16x24 grid; cameras yawed 0, +120, -120 degrees)
   with `packets.assemble.packet_from_support` in mode 'full', sharing one `SweepFeatures`.

Configurations: torch's default thread count, and one thread (torch.set_num_threads(1) plus
OMP/MKL/OpenBLAS thread variables set to 1 before any import). Times are wall seconds of one
run; only ratios within one run mean anything on a shared machine.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from typing import Any

from bench.measure import peak_rss_bytes
from schemas.errors import DataError

GOAL_GB = 4.0
N_POINTS = 64_000
C_U = 1224
N_VIEWS = 3
YAWS_DEG = (0.0, 120.0, -120.0)
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def view_cameras(n_views: int = N_VIEWS) -> list[Any]:
    """T_cam_lidar float64 (4, 4) of each view: the bench camera yawed about the LiDAR z axis."""
    import numpy as np

    from bench.packets_bench import T_CAM_LIDAR

    out = []
    for yaw in np.deg2rad(YAWS_DEG[:n_views]):
        rz = np.eye(4)
        rz[:2, :2] = [[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]]
        out.append(T_CAM_LIDAR @ rz)
    return out


def worker(n_points: int, channels: int, threads: int | None, n_views: int = N_VIEWS,
           seed: int = 0) -> dict[str, Any]:
    """Encode one sweep and pack it into `n_views` views in this process; return the figures.

    threads: None keeps torch's default thread count, else torch.set_num_threads(threads).
    """
    import numpy as np
    import torch

    from bench.packets_bench import HW, K, _sweep
    from model.encoders import get_point_encoder
    from packets.assemble import SweepFeatures, packet_from_support, view_support

    if threads is not None:
        torch.set_num_threads(threads)
    xyz = _sweep(np.random.default_rng(seed), n_points)               # (N, 3) float64 m
    enc = get_point_encoder("fpfh", channels=channels, seed=seed)
    rss_ready = peak_rss_bytes()["vm_hwm"]
    t0 = time.perf_counter()
    feat = SweepFeatures.from_array(enc.encode(xyz))                  # (N, C_u) float32
    t1 = time.perf_counter()
    rss_encoded = peak_rss_bytes()["vm_hwm"]
    occupied, per_view = 0, []
    for T in view_cameras(n_views):
        tv = time.perf_counter()
        sup = view_support(xyz, K, T, HW)
        packet = packet_from_support(sup, 0.02, feat, mode="full")
        per_view.append(time.perf_counter() - tv)
        assert packet.h is not None and packet.h.shape == (channels, 16, 24)
        occupied += packet.stats.n_occupied_cells
    t2 = time.perf_counter()
    rss = peak_rss_bytes()
    return {
        "threads": torch.get_num_threads(), "n_points": int(xyz.shape[0]), "c_u": channels,
        "views": n_views, "occupied_cells": occupied, "features_gb": feat.values.nbytes / 1e9,
        "encode_s": t1 - t0, "pack_s": t2 - t1, "pack_view_s": per_view,
        "peak_rss_gb": rss["vm_hwm"] / 1e9, "ru_maxrss_gb": rss["ru_maxrss"] / 1e9,
        "rss_before_encode_gb": rss_ready / 1e9, "peak_rss_after_encode_gb": rss_encoded / 1e9,
    }


def run_worker_subprocess(n_points: int, channels: int, threads: int | None,
                          n_views: int = N_VIEWS, timeout_s: float = 1800.0) -> dict[str, Any]:
    """Run `worker` in a fresh interpreter and return its figures (RuntimeError on failure)."""
    env = dict(os.environ)
    for var in _THREAD_VARS:
        env.pop(var, None)
        if threads is not None:
            env[var] = str(threads)
    cmd = [sys.executable, "-m", "bench.packing_bench", "--worker",
           str(n_points), str(channels), str(threads or 0), str(n_views)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout_s,
                          check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"packing worker {cmd[3:]} failed ({proc.returncode}): "
                           f"{proc.stderr.strip()[-2000:]}")
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"packing worker {cmd[3:]} printed no result: {proc.stdout[-500:]}")
    result: dict[str, Any] = json.loads(lines[-1])
    return result


def _best_of(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Fastest encode and pack times and the largest peak RSS over repeated worker runs."""
    best = dict(results[0])
    for key in ("encode_s", "pack_s"):
        best[key] = min(r[key] for r in results)
        best[f"{key}_all"] = [r[key] for r in results]
    for key in ("peak_rss_gb", "ru_maxrss_gb", "rss_before_encode_gb", "peak_rss_after_encode_gb"):
        best[key] = max(r[key] for r in results)
    best["pack_view_s"] = min((r["pack_view_s"] for r in results), key=sum)
    best["repeats"] = len(results)
    return best


def run_packing_rss_bench(n_points: int = N_POINTS, channels: int = C_U,
                          n_views: int = N_VIEWS, repeats: int = 3) -> dict[str, Any]:
    """Peak RSS and time split of one packing worker, default threads and one thread.

    Each configuration runs `repeats` times in fresh workers, interleaved; times are the
    fastest run (noise on a shared machine only adds time), peak RSS the largest.
    Returns `peak_rss_gb_per_worker` (the larger of both configurations; goal < 4 GB),
    `meets_goal`, per-configuration figures under `runs` ('default', 'one_thread'), and the
    ratios `pack_over_encode` (default threads) and `encode_one_over_default_threads`.
    """
    if repeats < 1:
        raise DataError(f"repeats={repeats} must be >= 1")
    raw: dict[str, list[dict[str, Any]]] = {"default": [], "one_thread": []}
    for _ in range(repeats):
        raw["default"].append(run_worker_subprocess(n_points, channels, None, n_views))
        raw["one_thread"].append(run_worker_subprocess(n_points, channels, 1, n_views))
    runs = {name: _best_of(results) for name, results in raw.items()}
    peak = max(r["peak_rss_gb"] for r in runs.values())
    d, one = runs["default"], runs["one_thread"]
    return {
        "peak_rss_gb_per_worker": peak,
        "meets_goal": peak < GOAL_GB,
        "goal_gb": GOAL_GB,
        "pack_over_encode": d["pack_s"] / d["encode_s"],
        "encode_one_over_default_threads": one["encode_s"] / d["encode_s"],
        "pack_one_over_default_threads": one["pack_s"] / d["pack_s"],
        "runs": runs,
    }


def _main(argv: list[str]) -> None:
    """`--worker N C THREADS VIEWS` (THREADS 0 = default): print the worker's JSON figures;
    no arguments: run the whole benchmark and print its JSON."""
    if argv[:1] == ["--worker"]:
        n, c, t, v = (int(a) for a in argv[1:5])
        print(json.dumps(worker(n, c, t or None, v)))
        return
    print(json.dumps(run_packing_rss_bench(), indent=2))


if __name__ == "__main__":
    _main(sys.argv[1:])
