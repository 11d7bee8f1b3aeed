"""The paper's controls on the science data: `m3gd bench science --suite paper`.

Tables (paper Tables 5-7, and time as a modelled quantity), every run trained like the
science bench's (`bench.science.train_run`: validation recordings pick the weights, the eval
recordings are only scored):
- packet modes: full, geom_only, zero, learnable (a learned data-independent packet: the
  capacity-matched control), no_lidar, from scratch; and the warp modes warp and full_warp
  (the target's packet gains the LiDAR reprojection of the source latents, schemas.modes),
  each paired with no_lidar, full and, per seed, with the baselines (`paired_vs_baselines`);
- training modes: freeze (start from the same seed's no_lidar network, train only the
  adapter) with and without LiDAR, finetune (start from it, train all), the all-views loss,
  no LiDAR dropout;
- M jointly synthesized targets: PSNR and seconds per target for M in {2, 3, 4} at
  K in {1, 5, 10, 20} (full, first seed), on clip indexes of 2 sources + M targets drawn
  from the same eval recordings;
- time: full with and without the delta-tau channel, on the clean data and on data whose
  training recordings carry an uncorrected camera clock offset, scored on the held-out
  targets whose |delta tau| exceeds the median.
Every row carries the baselines on the same targets and its margin over the strongest; the
hard subset (clips whose largest camera baseline exceeds the median of the scored clips) is
reported apart; differences are paired by seed (mean, std, per-seed values, paired t, p).
"""

from __future__ import annotations

import json
import statistics
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from bench.science import (
    QUICK,
    SciencePreset,
    ScienceSpec,
    eval_loss,
    load_net,
    save_net,
    timed_scores,
    train_run,
)
from bench.science_data import ScienceData, build_science_cache
from bench.science_paper_rows import (
    EXTRA_ROWS,
    PACKET_ROWS,
    VARIANTS,
    WARP_ROWS,
    WARP_TABLE,
    Variant,
)
from bench.science_paper_tables import aggregate_paper
from bench.science_tempered import TEMPERING, Tempering, choose_temperature, label
from model.dataset import ClipStream, load_clips
from model.evaluate import TargetResult
from model.net import M3GDNet
from model.scoring import _means
from pipeline.analysis.plots_science import plot_paper

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from pipeline.run.stage import Stage


@dataclass(frozen=True)
class PaperSuite:
    """Data, model and budget of the suite; which M and K the multi-target table uses."""

    preset: SciencePreset
    variants: tuple[Variant, ...] = VARIANTS
    ms: tuple[int, ...] = (2, 3, 4)
    m_ks: tuple[int, ...] = (1, 5, 10, 20)
    m_clips: int = 16
    clock_offset_s: float = 0.05
    ks: tuple[int, ...] = (1, 10)
    tempering: Tempering = TEMPERING

    def score_keys(self) -> tuple[int | str, ...]:
        """What every run is scored at: eval_k<K> for K in ks (the paper's sampler) and
        eval_k<K>_tval (the temperature the validation recordings chose)."""
        return (*self.ks, *self.tempering.labels())


CPU_PAPER = PaperSuite(
    SciencePreset(
        ScienceData(synth_seeds=(0, 1), seconds=6.0, points_per_sweep=2048, gap_min=4,
                    gap_max=12, eval_clips_per_recording=12),
        ScienceSpec(steps=1000, warmup_steps=20, batch_size=8, width=64, depth=2,
                    val_recordings=1, val_clips=16, val_every=100, eval_clips=24),
        seeds=(0, 1, 2)),
    m_clips=12)
"""The suite cut to a shared 2-core machine (`--suite paper-cpu`): 8 recordings of 6 s
(wide baselines), a 64-wide 2-deep network, 1000 steps, 3 seeds, 24 eval clips: each table
within ~30 CPU-minutes (measured 11.5-21.9, docs/benchmarks_model.md)."""

def with_rows(suite: PaperSuite, rows: Sequence[str]) -> PaperSuite:
    """`suite` cut to the variants named `rows` (and those they start from), without the
    M-target table (it is the full suite's); a ValueError names an unknown row."""
    known = {v.name: v for v in suite.variants}
    unknown = [r for r in rows if r not in known]
    if unknown:
        raise ValueError(f"unknown rows {unknown}; one of {list(known)}")
    keep = set(rows) | {known[r].init_from for r in rows if known[r].init_from}
    return replace(suite, variants=tuple(v for v in suite.variants if v.name in keep), ms=())


QUICK_PAPER = PaperSuite(replace(QUICK, seeds=(0,)), ms=(2, 3), m_ks=(1, 2), m_clips=2)
"""The same code path in minutes (for tests; numbers mean nothing)."""


def target_dtau(output_dir: Path, clips: list[dict[str, Any]]) -> dict[tuple[int, int], float]:
    """|delta tau| (s) of every view of `clips`, keyed (clip_id, view), from the cache's
    per-view dtau_s."""
    from schemas.cache_layout import GROUP_TEMPLATE
    from schemas.layout import OutputLayout
    from store.cache_io import read_views

    cache = OutputLayout(output_dir).cache
    out: dict[tuple[int, int], float] = {}
    for c in clips:
        group = cache / GROUP_TEMPLATE.format(recording=c["recording"], camera=c["camera"])
        dt = read_views(group / "dtau_s", [int(f) for f in c["frames"]])
        out |= {(int(c["clip_id"]), v): abs(float(x)) for v, x in enumerate(dt)}
    return out


def subsets(results: list[TargetResult], clips: list[dict[str, Any]],
            dtau: dict[tuple[int, int], float]) -> dict[str, Any]:
    """Means of all targets, of the hard clips (largest camera baseline above the median of
    the scored clips) and of the targets whose |delta tau| is above the median."""
    scored = {r.clip_id for r in results}
    base = {int(c["clip_id"]): float(c["max_baseline_m"]) for c in clips
            if int(c["clip_id"]) in scored}
    cut = statistics.median(base.values())
    dts = [dtau[(r.clip_id, r.view)] for r in results]
    dcut = statistics.median(dts)
    out: dict[str, Any] = {"all": _means(results), "hard_cut_m": cut, "dtau_cut_s": dcut}
    hard = [r for r in results if base[r.clip_id] > cut]
    large = [r for r, d in zip(results, dts, strict=True) if d > dcut]
    if hard:
        out["hard"] = _means(hard)
    if large:
        out["large_dtau"] = _means(large)
    return out


def paper_score(net: M3GDNet, output_dir: Path, mode: str, spec: ScienceSpec, steps: int,
                clips: int | None = None, temperature: float = 1.0) -> dict[str, Any]:
    """K-step samples of the first eval clips scored beside the baselines (`subsets`), with
    CPU and wall seconds per target (`timed_scores`); the start noise scaled by
    `temperature` (`model.sampler.sample`)."""
    stream = ClipStream(output_dir, "eval", mode, shuffle=False, with_images=True)
    n = spec.eval_clips if clips is None else clips
    timed = timed_scores(net, output_dir, stream, spec, steps, spec.guidance, clips=n,
                         keep_images=False, temperature=temperature)
    out = subsets(timed.results, stream.clips, target_dtau(output_dir, stream.clips[:n]))
    return out | {"targets": len(timed.results)} | timed.per_target()


def _run_file(workdir: Path, name: str, seed: int) -> Path:
    return workdir / "runs" / f"{name}-s{seed}.json"


def _net_dir(workdir: Path, name: str, seed: int) -> Path:
    return workdir / "nets" / f"{name}-s{seed}"


def score_run(net: M3GDNet, out_dir: Path, mode: str, spec: ScienceSpec,
              ks: tuple[int, ...], tempering: Tempering, have: frozenset[str] = frozenset()
              ) -> dict[str, Any]:
    """eval_k<K> for each K of `ks` (the paper's sampler) and eval_k<K>_tval for each K of
    `tempering` (the temperature the validation recordings chose, `choose_temperature`),
    leaving out the keys in `have`. Deterministic: the noise is seeded."""
    res: dict[str, Any] = {}
    for k in ks:
        if f"eval_k{k}" not in have:
            res[f"eval_k{k}"] = paper_score(net, out_dir, mode, spec, k)
    for k in tempering.ks:
        if f"eval_k{label(k)}" not in have:
            chosen = choose_temperature(net, out_dir, mode, spec, k, tempering.temperatures)
            res[f"eval_k{label(k)}"] = paper_score(net, out_dir, mode, spec, k,
                                                   temperature=chosen["temperature"]) | chosen
    return res


def run_variant(data: dict[str, Path], v: Variant, seed: int, spec: ScienceSpec,
                ks: tuple[int, ...], workdir: Path, tempering: Tempering = TEMPERING
                ) -> Path:
    """Train one (variant, seed), keep its network, score it (`score_run`); the run's JSON
    (atomic)."""
    from schemas.atomic_io import write_text_atomic

    torch.set_num_threads(spec.threads)
    c0, w0 = time.process_time(), time.perf_counter()
    init = (None if v.init_from is None
            else load_net(_net_dir(workdir, v.init_from, seed), spec.device))
    out_dir = data[v.data]
    spec = spec if v.anchor is None else replace(spec, anchor=v.anchor)
    run = train_run(out_dir, v.mode, seed, spec, {"dtau_channel": v.dtau_channel},
                    v.train_over(), init)
    save_net(run.net, _net_dir(workdir, v.name, seed))
    res: dict[str, Any] = {"variant": v.name, "mode": v.mode, "seed": seed, "device": spec.device,
                           "settings": asdict(v), "train_minutes": run.train_minutes,
                           "best_step": run.best_step, "best_weights": run.best_weights,
                           "val_loss": run.val_loss, "train_loss_last": run.losses[-20:],
                           "eval_loss": eval_loss(run.net, out_dir, v.mode, spec)}
    res |= score_run(run.net, out_dir, v.mode, spec, ks, tempering)
    res["cpu_minutes"] = (time.process_time() - c0) / 60  # this process: train + score
    res["wall_minutes"] = (time.perf_counter() - w0) / 60
    return write_text_atomic(_run_file(workdir, v.name, seed), json.dumps(res))


def rescore_variant(data: dict[str, Path], v: Variant, seed: int, spec: ScienceSpec,
                    ks: tuple[int, ...], workdir: Path, tempering: Tempering = TEMPERING
                    ) -> Path:
    """A finished run scored at what the suite now asks and it lacks, from its kept network
    (no training; the scores it has are kept as they are); the run's JSON (atomic)."""
    from schemas.atomic_io import write_text_atomic

    torch.set_num_threads(spec.threads)
    path = _run_file(workdir, v.name, seed)
    res = json.loads(path.read_text())
    net = load_net(_net_dir(workdir, v.name, seed), spec.device)
    res |= score_run(net, data[v.data], v.mode, spec, ks, tempering, frozenset(res))
    return write_text_atomic(path, json.dumps(res))


Job = tuple[dict[str, Path], Variant, int, ScienceSpec, tuple[int, ...], Path, Tempering]
"""The arguments of `run_variant` and `rescore_variant`."""


def _job(args: Job) -> Path:
    """Pool worker: `run_variant`."""
    return run_variant(*args)


def _rescore_job(args: Job) -> Path:
    """Pool worker: `rescore_variant`."""
    return rescore_variant(*args)


def _lacks_scores(workdir: Path, v: Variant, seed: int, keys: tuple[int | str, ...]) -> bool:
    """A finished run with a kept network that lacks a score the suite asks for."""
    path = _run_file(workdir, v.name, seed)
    if not path.exists() or not (_net_dir(workdir, v.name, seed) / "net.json").exists():
        return False
    return any(f"eval_k{k}" not in json.loads(path.read_text()) for k in keys)


def _map(jobs: int, fn: Callable[[Job], Path], todo: list[Job]) -> None:
    """fn over todo: in a pool of `jobs` processes when there is more than one of each."""
    from bench.worker_pool import spawn_pool

    if jobs > 1 and len(todo) > 1:
        with spawn_pool(jobs) as pool:
            list(pool.map(fn, todo))
    else:
        for job in todo:
            fn(job)


def run_variants(data: dict[str, Path], suite: PaperSuite, workdir: Path, jobs: int,
                 train_missing: bool) -> list[dict[str, Any]]:
    """Every (variant, seed) not yet finished, in two waves (runs that start from another
    variant's network wait for it), and every finished one that lacks a score the suite
    asks for scored from its kept network (none of either with train_missing False);
    returns the finished runs."""
    spec, seeds = suite.preset.spec, suite.preset.seeds
    for wave in ([v for v in suite.variants if v.init_from is None],
                 [v for v in suite.variants if v.init_from is not None]):
        todo: list[Job] = [(data, v, s, spec, suite.ks, workdir, suite.tempering)
                           for s in seeds for v in wave
                           if train_missing and not _run_file(workdir, v.name, s).exists()]
        _map(jobs, _job, todo)
    stale: list[Job] = [(data, v, s, spec, suite.ks, workdir, suite.tempering)
                        for s in seeds for v in suite.variants
                        if train_missing and _lacks_scores(workdir, v, s, suite.score_keys())]
    _map(jobs, _rescore_job, stale)
    return [json.loads(_run_file(workdir, v.name, s).read_text())
            for s in seeds for v in suite.variants if _run_file(workdir, v.name, s).exists()]


def m_target_index(output_dir: Path, m: int, workdir: Path, data: Any) -> Path:
    """An output dir sharing `output_dir`'s cache whose eval clips have 2 sources and `m`
    targets (drawn by `model.clips.sample_clips` from the same eval recordings, same gaps);
    the training rows are copied (the mean-image baselines read them)."""
    import pyarrow as pa

    from model.clips import sample_clips
    from schemas.cache_layout import GROUP_TEMPLATE, GroupAttrs
    from schemas.layout import OutputLayout
    from schemas.tables import CLIPS, write_table
    from store.cache_io import node_attrs, read_views

    src, out = OutputLayout(output_dir), workdir / f"m{m}"
    out.mkdir(parents=True, exist_ok=True)
    dst = OutputLayout(out)
    if not dst.cache.exists():
        dst.cache.symlink_to(src.cache.resolve(), target_is_directory=True)
    rows = load_clips(output_dir, "train")
    groups = sorted({(c["recording"], c["camera"]) for c in load_clips(output_dir, "eval")})
    for i, (rec, cam) in enumerate(groups):
        where = src.cache / GROUP_TEMPLATE.format(recording=rec, camera=cam)
        n = GroupAttrs.from_attrs(node_attrs(where), str(where)).n_views
        valid = np.flatnonzero(read_views(where / "valid", list(range(n)))).astype(np.int64)
        centres = read_views(where / "T_world_cam", list(range(n)))[:, :3, 3]
        for k in sample_clips(valid, centres, data.eval_clips_per_recording, "eval", 2 + m,
                              data.gap_min, data.gap_max, 1000 + i):
            rows.append({"split": "eval", "recording": rec, "camera": cam,
                         "frames": list(k.frames), "is_target": list(k.is_target),
                         "max_baseline_m": k.max_baseline_m, "hard": False})
    for j, row in enumerate(rows):
        row["clip_id"] = j
    write_table(pa.Table.from_pylist(rows, schema=CLIPS), CLIPS, dst.clips)
    return out


def psnr_by_m(output_dir: Path, suite: PaperSuite, workdir: Path) -> dict[str, Any]:
    """M -> K -> PSNR, SSIM, baselines and seconds per target of the first seed's full
    network (workdir/psnr_by_m.json is reused by a rerun)."""
    from schemas.atomic_io import write_text_atomic

    cached = workdir / "psnr_by_m.json"
    if cached.exists():
        done: dict[str, Any] = json.loads(cached.read_text())
        return done
    torch.set_num_threads(suite.preset.spec.threads)
    net = load_net(_net_dir(workdir, "full", suite.preset.seeds[0]),
                   suite.preset.spec.device)
    table: dict[str, Any] = {}
    for m in suite.ms:
        where = m_target_index(output_dir, m, workdir / "m_targets", suite.preset.data)
        table[str(m)] = {}
        for k in suite.m_ks:
            r = paper_score(net, where, "full", suite.preset.spec, k, suite.m_clips)
            table[str(m)][str(k)] = {
                "psnr": r["all"]["psnr_mean"], "ssim": r["all"]["ssim_mean"],
                "targets": r["targets"], "seconds_per_target": r["seconds_per_target"],
                "wall_seconds_per_target": r["wall_seconds_per_target"],
                "margin_db": r["all"].get("margin_db"),
                "baselines": r["all"].get("baselines", {})}
    write_text_atomic(cached, json.dumps(table))
    return table


PAPER_HEADLINE = (*(f"psnr_k{k}_{m}" for k in (1, 10, label(1), label(10))
                    for m in (*PACKET_ROWS, *WARP_ROWS, *EXTRA_ROWS)),
                  *(f"psnr_k1_{m}_std" for m in (*PACKET_ROWS, *WARP_ROWS, *EXTRA_ROWS)),
                  "psnr_copy_source", "psnr_mean_latent", "psnr_mean_image",
                  "psnr_reprojection", "reprojection_margin_db",
                  *(f"reproj_err_k{k}_{m}" for k in (1, 10) for m in WARP_TABLE),
                  "reproj_err_ground_truth", "reproj_err_copy_source", "reproj_err_mean_latent",
                  "reproj_err_reprojection",
                  "strongest_baseline", "freeze_lidar_gain_db", "freeze_lidar_gain_db_std",
                  "dtau_channel_effect_db", "dtau_channel_effect_db_std",
                  "dtau_channel_effect_offset_db", "clock_offset_effect_db", "psnr_by_m",
                  "wall_minutes")
"""Keys `m3gd bench science --suite paper` prints (paper.json holds everything)."""


def run_paper(suite: PaperSuite, workdir: Path, stages: Sequence[Stage],
              cache: Path | None = None, jobs: int = 1,
              train_missing: bool = True) -> dict[str, Any]:
    """Build (or reuse) the clean and the clock-offset caches, train and score every
    (variant, seed), the multi-target table, aggregate; workdir/paper.json."""
    from schemas.atomic_io import write_text_atomic

    t0 = time.perf_counter()
    data = {"clean": cache or build_science_cache(workdir / "data", suite.preset.data, stages)}
    if any(v.data == "offset" for v in suite.variants):
        offset = replace(suite.preset.data, train_clock_offset_s=suite.clock_offset_s)
        data["offset"] = build_science_cache(workdir / "data_offset", offset, stages)
    runs = run_variants(data, suite, workdir, jobs, train_missing)
    result = aggregate_paper(runs, suite.score_keys())
    if suite.ms and any(r["variant"] == "full" for r in runs):
        result["psnr_by_m"] = psnr_by_m(data["clean"], suite, workdir)
    result |= {"runs": runs, "seeds": list(suite.preset.seeds),
               "variants": [asdict(v) for v in suite.variants],
               "data": asdict(suite.preset.data), "spec": asdict(suite.preset.spec),
               "clock_offset_s": suite.clock_offset_s,
               "caches": {k: str(v) for k, v in data.items()},
               "wall_minutes": (time.perf_counter() - t0) / 60}
    result["plots"] = [str(plot_paper(result, workdir / "plots" / "science_paper.png"))]
    write_text_atomic(workdir / "paper.json", json.dumps(result, indent=1))
    return result
