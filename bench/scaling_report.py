"""Markdown tables of the scaling estimate: raw measured costs, assumptions, release table.

`python -m bench.scaling_report [COSTS.json ...]` measures the per-item costs here 3
times in one-thread workers (`measure_in_worker`), or reads them from JSON files of earlier
runs; several runs are merged key by key with `merge_best` (the least disturbed run), and the
tables of docs/scaling.md are printed.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

from bench.scaling import (
    Assumptions,
    default_scenarios,
    scaling_table,
    stage_work_s,
    stored_bytes_per_view,
)
from schemas.errors import DataError

N_WORKERS = (1, 2, 8, 32, 128)
COST_NOTES = {
    "ingest_image_s": "s/image: deserialize CompressedImage + JPEG decode (reduced) + remap",
    "jpeg_bytes": "bytes of the synthetic 1920x1280 JPEG (quality 90)",
    "jpeg_reduction": "JPEG decode reduction chosen by the rectifier",
    "decode_sweep_s": "s/sweep: deserialize PointCloud2 + decode_cloud",
    "sweep_bytes": "bytes of one PointCloud2 payload (point_step 26)",
    "n_points": "points per sweep",
    "select_view_s": "s/view: nearest sweep + odometry chain + Arrow row",
    "encode_patch_image_s": "s/image: embedded patch encoder (768 ch)",
    "encode_da3_image_s": "s/image: DA3-Base backbone, random init, levels (0,)",
    "encode_fpfh_sweep_s": "s/sweep: embedded fpfh encoder",
    "packet_view_s": "s/view: support sets + [g; h] + float16 cast",
    "occupancy": "fraction of the 16x24 cells with points",
    "cache_write_bytes_s": "bytes/s: Zarr write (uncompressed bytes), one writer",
    "packet_bytes_ratio": "packet bytes on disk / raw (g zstd, h occupied cells only)",
    "image_bytes_view": "bytes/view: rectified image 224x336x3 uint8",
    "latent_bytes_view": "bytes/view: latent (C, 16, 24) float16",
    "packet_raw_bytes_view": "bytes/view: g float32 + h float16, uncompressed",
    "meta_bytes_view": "bytes/view: stamps, K, poses, valid",
    "point_channels": "C_u",
    "torch_threads": "torch threads during the measurement",
    "load_avg_1min": "1-minute load average of this 2-core machine during the run",
    "blas_threads_env": "OpenBLAS/OpenMP threads set in the environment (0: library default)",
}
"""What each key means; timed keys `<stage>_s` are process CPU seconds (used by the model)."""


def _fmt(x: float | str) -> str:
    """A number with 3-4 significant digits, or the string itself."""
    if isinstance(x, str):
        return x
    if isinstance(x, bool):
        return str(x)
    if isinstance(x, int):
        return f"{x:,}"
    if x == 0 or 1e-3 <= abs(x) < 1e6:
        return f"{x:.4g}"
    return f"{x:.3e}"


def costs_table(costs: Mapping[str, float]) -> str:
    """Markdown table of the raw measured figures."""
    lines = ["| key | value | meaning |", "|---|---|---|"]
    for k, v in costs.items():
        note = COST_NOTES.get(k, "wall-clock seconds of the same" if k.endswith("_wall_s") else "")
        lines.append(f"| `{k}` | {_fmt(v)} | {note} |")
    return "\n".join(lines)


def runs_table(runs: Sequence[Mapping[str, float]]) -> str:
    """Markdown table of the timed keys and rates of each run, side by side."""
    keys = [k for k in runs[0] if k.endswith("_s") and not k.startswith("_")] + ["load_avg_1min"]
    lines = ["| key | " + " | ".join(f"run {i + 1}" for i in range(len(runs))) + " |",
             "|---|" + "---|" * len(runs)]
    lines += [f"| `{k}` | " + " | ".join(_fmt(float(r[k])) if k in r else "" for r in runs) + " |"
              for k in keys]
    return "\n".join(lines)


def assumptions_table(a: Assumptions) -> str:
    """Markdown table of the release assumptions and the encoder scenarios."""
    lines = ["| assumption | value |", "|---|---|"]
    lines += [f"| {f.name} | {_fmt(getattr(a, f.name))} |" for f in fields(a)
              if f.name != "scenarios"]
    lines += ["", "| scenario | image encoder s/image | point encoder s/sweep | source |",
              "|---|---|---|---|"]
    lines += [f"| {s.name} | {_fmt(s.image_encoder_s)} | {_fmt(s.point_encoder_s)} | {s.source} |"
              for s in a.scenarios]
    return "\n".join(lines)


def work_table(costs: Mapping[str, float], a: Assumptions) -> str:
    """Markdown table of single-worker hours per stage and scenario."""
    lines = ["| scenario | ingest h | select h | encode h | packets h | total CPU h |",
             "|---|---|---|---|---|---|"]
    for sc in a.scenarios:
        w = {k: v / 3600.0 for k, v in stage_work_s(costs, sc, a).items()}
        lines.append(f"| {sc.name} | {_fmt(w['ingest'])} | {_fmt(w['select'])} | "
                     f"{_fmt(w['encode'])} | {_fmt(w['packets'])} | {_fmt(sum(w.values()))} |")
    return "\n".join(lines)


HEADERS = {"hours_ingest": "ingest h", "hours_encode": "encode h", "hours_packets": "packets h",
           "io_hours": "I/O h", "storage_tb": "storage TB"}
"""Column headers in words (a page of 1280 px fits the table with no scrolling)."""


def release_table(rows: Sequence[Mapping[str, float | str]]) -> str:
    """Markdown table of the scaling rows (hours are wall-clock lower bounds)."""
    cols = ("scenario", "workers", "hours", "days", "bound", "hours_ingest", "hours_encode",
            "hours_packets", "io_hours", "speedup", "efficiency", "storage_tb")
    lines = ["| " + " | ".join(HEADERS.get(c, c) for c in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        vals = [r["days"] if c == "days" else r[c] for c in cols]
        lines.append("| " + " | ".join(_fmt(v) for v in vals) + " |")
    return "\n".join(lines)


def render(costs: Mapping[str, float], a: Assumptions,
           n_workers: Sequence[int] = N_WORKERS) -> str:
    """All tables of docs/scaling.md for these costs and assumptions."""
    rows = scaling_table(costs, n_workers, a)
    for r in rows:
        r["days"] = float(r["hours"]) / 24.0
    per_view = stored_bytes_per_view(costs)
    return "\n\n".join([
        "### Measured per-item costs\n\n" + costs_table(costs),
        "### Assumptions\n\n" + assumptions_table(a),
        "### Single-worker work per stage\n\n" + work_table(costs, a),
        f"### Release on N workers\n\nStored per view: {per_view / 1e6:.3f} MB.\n\n"
        + release_table(rows),
    ])


RATE_KEYS = ("cache_write_bytes_s",)
"""Keys that are rates (higher is better); every other `_s` key is seconds per item."""


def merge_best(runs: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """Best of several cost dicts, key by key (keys present in every run): the least time per
    item, the highest rate, the highest load average seen; other figures from the first run."""
    keys = [k for k in runs[0] if all(k in r for r in runs)]
    out = {}
    for k in keys:
        vals = [float(r[k]) for r in runs]
        if k in RATE_KEYS or k == "load_avg_1min":
            out[k] = max(vals)
        elif k.endswith("_s"):
            out[k] = min(vals)
        else:
            out[k] = vals[0]
    return out


def with_wall_times(costs: Mapping[str, float]) -> dict[str, float]:
    """A copy whose per-item seconds `<stage>_s` are the wall-clock `<stage>_wall_s` figures."""
    out = dict(costs)
    for k, v in costs.items():
        if k.endswith("_wall_s"):
            out[k.removesuffix("_wall_s") + "_s"] = v
    return out


def variant_tables(costs: Mapping[str, float], n_workers: Sequence[int] = N_WORKERS) -> str:
    """Release tables of two variants with the default scenarios: wall-clock per-item costs,
    and packets planned per shard row instead of per recording."""
    wall = with_wall_times(costs)
    rows_wall = scaling_table(wall, n_workers, Assumptions(default_scenarios(wall)))
    per_row = Assumptions(default_scenarios(costs), packets_per_shard_row=True)
    rows_row = scaling_table(costs, n_workers, per_row)
    days = [[{**r, "days": float(r["hours"]) / 24.0} for r in rows] for rows in
            (rows_wall, rows_row)]
    return "\n\n".join([
        "### Variant: wall-clock per-item costs\n\n" + release_table(days[0]),
        "### Variant: packets planned per shard row\n\n" + release_table(days[1]),
    ])


def markdown(runs: Sequence[Mapping[str, float]], n_workers: Sequence[int] = N_WORKERS) -> str:
    """The tables of docs/scaling.md from one or more measured cost dicts."""
    clean = [{k: v for k, v in r.items() if not k.startswith("_")} for r in runs]
    costs = merge_best(clean)
    return "\n\n".join(["### Runs\n\n" + runs_table(clean),
                         render(costs, Assumptions(default_scenarios(costs)), n_workers),
                         variant_tables(costs, n_workers)])


def run_costs_bench(runs: int = 3, n_workers: Sequence[int] = N_WORKERS,
                    **measure_kwargs: Any) -> dict[str, Any]:
    """Measure `runs` times in one-thread workers; return {'runs': [...], 'costs': merged,
    'rows': scaling rows (default assumptions), 'markdown': the tables} (for `m3gd bench costs`).
    measure_kwargs go to `measure_item_costs` (e.g. tiny sizes in tests)."""
    from bench.costs import measure_in_worker

    if runs < 1:
        raise DataError(f"runs={runs} must be >= 1")
    measured = [measure_in_worker(**measure_kwargs) for _ in range(runs)]
    costs = merge_best(measured)
    rows = scaling_table(costs, n_workers, Assumptions(default_scenarios(costs)))
    return {"runs": measured, "costs": costs, "rows": rows,
            "markdown": markdown(measured, n_workers)}


def _main(argv: list[str]) -> None:
    """Print the tables from JSON cost files given, or from 3 fresh measurements."""
    if argv:
        print(markdown([json.loads(Path(p).read_text()) for p in argv]))
    else:
        print(run_costs_bench()["markdown"])


if __name__ == "__main__":
    _main(sys.argv[1:])
