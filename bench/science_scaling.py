"""Data scaling of the paper-cpu suite: `m3gd bench science --suite paper-cpu --recordings
8,32,128`.

The suite's network, steps and scoring stay fixed; only the training recordings grow. A point
of N recordings trains on the 4 scenes (`bench.science_data.SCENES`) at N / 4 synth seeds (the
first ones not among the evaluation seeds; one of them held out for validation as in every
science run) and is scored on the same held-out targets at every point: the clips of the 4
scenes at the evaluation seeds (`EVAL_SEEDS`), scenes nobody trains, validates or tunes on.
The points of one invocation share one growing cache (`workdir/data-<largest point>`: the
pipeline adds the new recordings), so two invocations (e.g. 8,32 and 128) build and train
side by side and a third with `--only-finished` tables them all; each point reads the cache
through its own clip index (`point_index`: a symlinked cache and a clips table of its training
recordings and the fixed eval clips), as the M-target table does.

Per point the runs are the paper suite's (`bench.science_paper.run_variants`: train, pick the
weights on validation, score at K = 1 and 10 with the paper's sampler and at the
validation-chosen temperature); `scaling_table` (pure) turns their JSON into the table: every
row beside every baseline, warp_x minus the strongest baseline (per seed, on the same
targets) and full minus no_lidar (paired by seed), each with its spread.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.science_data import SCENES, ScienceData, build_science_cache
from bench.science_paper import CPU_PAPER, PaperSuite, run_variants, with_rows
from bench.science_paper_tables import aggregate_paper, paired
from bench.science_report import _mean_std
from bench.science_scaling_plot import plot_scaling
from model.evaluate import RANKED_BASELINES

if TYPE_CHECKING:
    from collections.abc import Sequence

    from pipeline.run.stage import Stage

EVAL_SEEDS = (20, 21)
"""Synth seeds of the held-out recordings (every scene at each): never trained or tuned on."""
ROWS = ("no_lidar", "full", "warp_x")
"""The table's rows: the floor, the paper's packets, and warp with the x loss."""
DIFFERENCES = {"warp_x - strongest": ("warp_x", None), "full - no_lidar": ("full", "no_lidar")}
"""The two differences the table follows across points (None: the strongest baseline)."""


@dataclass(frozen=True)
class ScalingSuite:
    """The paper-cpu suite (cut to `ROWS`) at several training set sizes.

    recordings: training recordings per point (multiples of the 4 scenes, validation one
    included); seeds: training seeds per point (0 .. n-1; fewer at the largest points, said
    in the table); eval_clips_per_recording: eval clips drawn from each held-out recording
    (2 sources + 2 targets each: 8 recordings x 3 = the suite's 24 clips, 48 targets)."""

    paper: PaperSuite
    recordings: tuple[int, ...] = (8, 32, 128)
    seeds: tuple[int, ...] = (3, 3, 1)
    eval_seeds: tuple[int, ...] = EVAL_SEEDS
    eval_clips_per_recording: int = 3

    def __post_init__(self) -> None:
        if len(self.seeds) != len(self.recordings):
            raise ValueError(f"{len(self.recordings)} points {self.recordings} but seeds per "
                             f"point {self.seeds}")
        for n in self.recordings:
            train_seeds(n, self.eval_seeds)  # raises on a size the scenes do not divide

    def points(self) -> list[tuple[int, tuple[int, ...], tuple[int, ...]]]:
        """(recordings, synth seeds trained on, training seeds) per point, smallest first."""
        return [(n, train_seeds(n, self.eval_seeds), tuple(range(s)))
                for n, s in sorted(zip(self.recordings, self.seeds, strict=True))]

    def data(self, synth_seeds: tuple[int, ...]) -> ScienceData:
        """The suite's data at the training `synth_seeds` and the evaluation seeds."""
        return replace(self.paper.preset.data, synth_seeds=(*synth_seeds, *self.eval_seeds))


def train_seeds(recordings: int, eval_seeds: Sequence[int] = EVAL_SEEDS) -> tuple[int, ...]:
    """The synth seeds of `recordings` training recordings (every scene at each): the first
    recordings / 4 non-negative seeds that are not evaluation seeds; a ValueError when the
    scenes do not divide `recordings` or fewer than 2 recordings remain (one validates)."""
    per, held = len(SCENES), set(eval_seeds)
    if recordings % per or recordings < per:
        raise ValueError(f"{recordings} recordings: a multiple of the {per} scenes {SCENES}")
    seeds: list[int] = []
    s = 0
    while len(seeds) < recordings // per:
        if s not in held:
            seeds.append(s)
        s += 1
    return tuple(seeds)


def scaling_suite(recordings: Sequence[int], seeds: Sequence[int] | None = None,
                  rows: Sequence[str] = ROWS, paper: PaperSuite = CPU_PAPER) -> ScalingSuite:
    """The suite at `recordings` per point, `seeds` per point (default: the paper suite's
    count at each), cut to `rows` (`with_rows`: a ValueError names an unknown row)."""
    n = len(paper.preset.seeds)
    per_point = tuple(seeds) if seeds is not None else (n,) * len(recordings)
    return ScalingSuite(with_rows(paper, rows), tuple(recordings), per_point)


def point_index(cache_dir: Path, out: Path, train: set[str], held_out: set[str],
                data: ScienceData, eval_clips: int, views: int) -> Path:
    """An output dir `out` reading `cache_dir`'s cache (symlinked) whose clips table holds
    the training clips of the recordings `train` (every valid frame a start, as the clips
    stage draws them) and `eval_clips` eval clips of each recording of `held_out`; each
    recording's draws are seeded by its name, so a recording gives the same clips at every
    point. Rewritten on every call (cheap)."""
    import zlib

    import numpy as np
    import pyarrow as pa

    from model.clips import sample_clips
    from schemas.cache_layout import GROUP_TEMPLATE, GroupAttrs
    from schemas.layout import OutputLayout
    from schemas.tables import CLIPS, write_table
    from store.cache_io import node_attrs, read_views

    src, dst = OutputLayout(cache_dir), OutputLayout(out)
    out.mkdir(parents=True, exist_ok=True)
    if not dst.cache.exists():
        dst.cache.symlink_to(src.cache.resolve(), target_is_directory=True)
    rows: list[dict[str, Any]] = []
    for split, names in (("train", sorted(train)), ("eval", sorted(held_out))):
        for rec in names:
            where = src.cache / GROUP_TEMPLATE.format(recording=rec, camera="front")
            n = GroupAttrs.from_attrs(node_attrs(where), str(where)).n_views
            valid = np.flatnonzero(read_views(where / "valid", list(range(n)))).astype(np.int64)
            centres = read_views(where / "T_world_cam", list(range(n)))[:, :3, 3]
            count = n if split == "train" else eval_clips
            rows.extend({"split": split, "recording": rec, "camera": "front",
                         "frames": list(k.frames), "is_target": list(k.is_target),
                         "max_baseline_m": k.max_baseline_m, "hard": False}
                        for k in sample_clips(valid, centres, count, split, views,
                                              data.gap_min, data.gap_max,
                                              zlib.crc32(f"{split}/{rec}".encode())))
    for j, row in enumerate(rows):
        row["clip_id"] = j
    write_table(pa.Table.from_pylist(rows, schema=CLIPS), CLIPS, dst.clips)
    return out


def mission_names(synth_seeds: Sequence[int]) -> set[str]:
    """The mission names of every scene at `synth_seeds` (`bench.science_data.science_config`)."""
    return {f"synth-{s}-s{seed}" for seed in synth_seeds for s in SCENES}


def _strongest_margins(runs: list[dict[str, Any]], k: int | str) -> dict[str, Any]:
    """Per seed, the run's PSNR minus the strongest baseline on the same targets at K = k
    (`margin_strongest_db` of `model.scoring._means`): mean, std, values, baseline names."""
    parts = [(r["seed"], r[f"eval_k{k}"]["all"]) for r in runs if f"eval_k{k}" in r]
    parts = [(s, p) for s, p in parts if "margin_strongest_db" in p]
    if not parts:
        return {}
    values = [float(p["margin_strongest_db"]) for _, p in sorted(parts, key=lambda x: x[0])]
    mean, std = _mean_std(values)
    return {"mean": mean, "std": std, "values": values,
            "baseline": sorted({str(p["strongest_baseline"]) for _, p in parts})}


def point_table(runs: list[dict[str, Any]], ks: tuple[int | str, ...]) -> dict[str, Any]:
    """One point's table from its finished runs (pure): per row and K the PSNR mean and std
    over seeds (`aggregate_paper`), every baseline's PSNR on the same targets (the strongest
    among `RANKED_BASELINES`: the recording-mean oracle is reference only), and the
    differences of `DIFFERENCES` per K (the strongest-baseline one per seed, the row pair
    paired by seed): {"mean", "std", "values", ...}; {} for a K no run was scored at."""
    agg = aggregate_paper(runs, ks)
    by = {n: sorted((r for r in runs if r["variant"] == n), key=lambda r: r["seed"])
          for n in dict.fromkeys(r["variant"] for r in runs)}
    rows = {n: {key: v for key, v in row.items()
                if key.startswith(("psnr_k", "ssim_k", "temperature_k", "cpu_minutes", "seeds"))
                and "_hard" not in key and "_dtau" not in key}
            for n, row in agg["rows"].items()}
    diffs: dict[str, dict[str, Any]] = {}
    for name, (a, b) in DIFFERENCES.items():
        if a not in by or (b is not None and b not in by):
            continue
        diffs[name] = {str(k): (_strongest_margins(by[a], k) if b is None
                                else paired(by[a], by[b], k)) for k in ks}
    base = agg["baselines"].get("all", {})
    ranked = [b for b in base if b in RANKED_BASELINES]  # the oracle is reference only
    return {"rows": rows, "baselines": {b: v["psnr_mean"] for b, v in base.items()},
            "strongest_baseline": max(ranked, key=lambda b: base[b]["psnr_mean"]) if ranked
            else None, "differences": diffs}


def scaling_table(points: dict[int, list[dict[str, Any]]], ks: tuple[int | str, ...]
                  ) -> dict[str, Any]:
    """The table across points (pure): recordings -> `point_table`, and per difference and K
    the series [(recordings, mean, std, seeds)] the plot draws, smallest point first."""
    table = {str(n): point_table(runs, ks) for n, runs in sorted(points.items()) if runs}
    series: dict[str, dict[str, list[list[float]]]] = {}
    for name in DIFFERENCES:
        for k in ks:
            pts = [[float(n), d["mean"], d["std"], float(len(d["values"]))]
                   for n, t in table.items()
                   if (d := t["differences"].get(name, {}).get(str(k)))]
            if pts:
                series.setdefault(name, {})[str(k)] = pts
    return {"points": table, "series": series}


def _point_runs(data_dir: Path, suite: ScalingSuite, n: int, synth: tuple[int, ...],
                seeds: tuple[int, ...], workdir: Path, stages: Sequence[Stage], jobs: int,
                train_missing: bool) -> list[dict[str, Any]]:
    """Build (grow) the shared cache to this point's recordings, write its clip index, train
    and score its runs (`run_variants`, finished ones reused); with train_missing False only
    the finished runs ([] for a point never started)."""
    where = workdir / f"n{n}"
    index = where / "index"
    if not train_missing and not (index / "clips.parquet").exists():
        return []  # a point never started: nothing finished
    if train_missing:
        build_science_cache(data_dir, suite.data(synth), stages)
        point_index(data_dir / "run", index,
                    mission_names(synth), mission_names(suite.eval_seeds),
                    suite.data(synth), suite.eval_clips_per_recording, 4)
    paper = replace(suite.paper, preset=replace(suite.paper.preset, seeds=seeds))
    return run_variants({"clean": index}, paper, where, jobs, train_missing)


def json_name(suite: ScalingSuite) -> str:
    """The table's file in the workdir: scaling_<points>.json (e.g. scaling_8-32-128.json)."""
    return f"scaling_{'-'.join(str(n) for n in sorted(suite.recordings))}.json"


def run_scaling(suite: ScalingSuite, workdir: Path, stages: Sequence[Stage], jobs: int = 1,
                train_missing: bool = True) -> dict[str, Any]:
    """Every point smallest first (the cache grows as it goes); after each point the table
    so far is written to workdir/`json_name` (atomic), so a stopped run keeps its finished
    points; returns the last table."""
    from schemas.atomic_io import write_text_atomic

    t0 = time.perf_counter()
    ks = suite.paper.score_keys()
    points: dict[int, list[dict[str, Any]]] = {}
    walls: dict[str, float] = {}
    result: dict[str, Any] = {}
    for n, synth, seeds in suite.points():
        c0 = time.perf_counter()
        data_dir = workdir / f"data-{max(suite.recordings)}"
        points[n] = _point_runs(data_dir, suite, n, synth, seeds, workdir, stages, jobs,
                                train_missing)
        result = scaling_table(points, ks) | {
            "recordings": list(suite.recordings), "seeds_per_point": list(suite.seeds),
            "eval_seeds": list(suite.eval_seeds), "train_synth_seeds": {
                str(m): list(s) for m, s, _ in suite.points()},
            "rows": [v.name for v in suite.paper.variants],
            "spec": asdict(suite.paper.preset.spec), "data": asdict(suite.paper.preset.data),
            "wall_minutes": (time.perf_counter() - t0) / 60}
        walls[str(n)] = (time.perf_counter() - c0) / 60
        for m, wall in walls.items():
            if m in result["points"]:
                result["points"][m]["wall_minutes"] = wall
        result["plot"] = str(plot_scaling(result, workdir / "plots" / (
            json_name(suite).removesuffix(".json") + ".png")))
        write_text_atomic(workdir / json_name(suite), json.dumps(result, indent=1))
    return result
