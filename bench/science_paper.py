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
    ScienceData,
    SciencePreset,
    ScienceSpec,
    build_science_cache,
    eval_loss,
    load_net,
    save_net,
    train_run,
    training_recordings,
)
from bench.science_paper_rows import (
    EXTRA_ROWS,
    PACKET_ROWS,
    VARIANTS,
    WARP_ROWS,
    WARP_TABLE,
    Variant,
)
from bench.science_report import _mean_std, _paired_t, reproj_baselines
from bench.science_tempered import TEMPERING, Tempering, choose_temperature, label
from model.dataset import ClipStream, load_clips
from model.evaluate import TargetResult
from model.net import M3GDNet
from model.scoring import _means, image_decoder, mean_images, score_clips
from pipeline.analysis.plots_science import plot_paper

if TYPE_CHECKING:
    from collections.abc import Sequence

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
    from schemas.cache_io import read_views
    from schemas.cache_layout import GROUP_TEMPLATE
    from schemas.layout import OutputLayout

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
    CPU and wall seconds per target (one thread; the mean images are built before); the
    start noise scaled by `temperature` (`model.sampler.sample`)."""
    stream = ClipStream(output_dir, "eval", mode, shuffle=False, with_images=True)
    decoder = image_decoder(stream, 0)
    trained = training_recordings(output_dir, spec)
    mean_images(stream, trained)
    n = spec.eval_clips if clips is None else clips
    t0, w0 = time.process_time(), time.perf_counter()
    results = score_clips(net, stream, decoder, n, spec.batch_size, steps, spec.guidance,
                          None, 0, keep_images=False, train_recordings=trained,
                          temperature=temperature)
    cpu, wall = time.process_time() - t0, time.perf_counter() - w0
    out = subsets(results, stream.clips, target_dtau(output_dir, stream.clips[:n]))
    out |= {"targets": len(results), "seconds_per_target": cpu / len(results),
            "wall_seconds_per_target": wall / len(results)}
    return out


def _run_file(workdir: Path, name: str, seed: int) -> Path:
    return workdir / "runs" / f"{name}-s{seed}.json"


def _net_dir(workdir: Path, name: str, seed: int) -> Path:
    return workdir / "nets" / f"{name}-s{seed}"


def run_variant(data: dict[str, Path], v: Variant, seed: int, spec: ScienceSpec,
                ks: tuple[int, ...], workdir: Path, tempering: Tempering = TEMPERING
                ) -> Path:
    """Train one (variant, seed), keep its network, score it at each K of `ks` and at each
    K of `tempering` with the temperature the validation recordings chose; the run's JSON
    (atomic)."""
    from schemas.atomic_io import write_text_atomic

    torch.set_num_threads(spec.threads)
    c0, w0 = time.process_time(), time.perf_counter()
    init = None if v.init_from is None else load_net(_net_dir(workdir, v.init_from, seed))
    out_dir = data[v.data]
    spec = spec if v.anchor is None else replace(spec, anchor=v.anchor)
    run = train_run(out_dir, v.mode, seed, spec, {"dtau_channel": v.dtau_channel},
                    v.train_over(), init)
    save_net(run.net, _net_dir(workdir, v.name, seed))
    res: dict[str, Any] = {"variant": v.name, "mode": v.mode, "seed": seed,
                           "settings": asdict(v), "train_minutes": run.train_minutes,
                           "best_step": run.best_step, "best_weights": run.best_weights,
                           "val_loss": run.val_loss, "train_loss_last": run.losses[-20:],
                           "eval_loss": eval_loss(run.net, out_dir, v.mode, spec)}
    for k in ks:
        res[f"eval_k{k}"] = paper_score(run.net, out_dir, v.mode, spec, k)
    for k in tempering.ks:
        chosen = choose_temperature(run.net, out_dir, v.mode, spec, k, tempering.temperatures)
        res[f"eval_k{label(k)}"] = paper_score(run.net, out_dir, v.mode, spec, k,
                                               temperature=chosen["temperature"]) | chosen
    res["cpu_minutes"] = (time.process_time() - c0) / 60  # this process: train + score
    res["wall_minutes"] = (time.perf_counter() - w0) / 60
    return write_text_atomic(_run_file(workdir, v.name, seed), json.dumps(res))


def _job(args: tuple[dict[str, Path], Variant, int, ScienceSpec, tuple[int, ...], Path,
                     Tempering]) -> Path:
    """Pool worker: `run_variant`."""
    return run_variant(*args)


def run_variants(data: dict[str, Path], suite: PaperSuite, workdir: Path, jobs: int,
                 train_missing: bool) -> list[dict[str, Any]]:
    """Every (variant, seed) not yet finished, in two waves (runs that start from another
    variant's network wait for it); returns the finished runs."""
    from bench.worker_pool import spawn_pool

    spec, seeds = suite.preset.spec, suite.preset.seeds
    for wave in ([v for v in suite.variants if v.init_from is None],
                 [v for v in suite.variants if v.init_from is not None]):
        todo = [(data, v, s, spec, suite.ks, workdir, suite.tempering)
                for s in seeds for v in wave
                if train_missing and not _run_file(workdir, v.name, s).exists()]
        if jobs > 1 and len(todo) > 1:
            with spawn_pool(jobs) as pool:
                list(pool.map(_job, todo))
        else:
            for job in todo:
                _job(job)
    return [json.loads(_run_file(workdir, v.name, s).read_text())
            for s in seeds for v in suite.variants if _run_file(workdir, v.name, s).exists()]


def m_target_index(output_dir: Path, m: int, workdir: Path, data: Any) -> Path:
    """An output dir sharing `output_dir`'s cache whose eval clips have 2 sources and `m`
    targets (drawn by `model.clips.sample_clips` from the same eval recordings, same gaps);
    the training rows are copied (the mean-image baselines read them)."""
    import pyarrow as pa

    from model.clips import sample_clips
    from schemas.cache_io import node_attrs, read_views
    from schemas.cache_layout import GROUP_TEMPLATE, GroupAttrs
    from schemas.layout import OutputLayout
    from schemas.tables import CLIPS, write_table

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
    net = load_net(_net_dir(workdir, "full", suite.preset.seeds[0]))
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


def _value(run: dict[str, Any], k: int | str, subset: str, metric: str = "psnr_mean"
           ) -> float | None:
    part = run.get(f"eval_k{k}", {}).get(subset)  # None for a run scored before the key
    return None if part is None or metric not in part else float(part[metric])


def paired(a: list[dict[str, Any]], b: list[dict[str, Any]], k: int | str, subset: str = "all"
           ) -> dict[str, Any]:
    """PSNR of a minus b, paired by seed, at K = k on `subset`: mean, std, per-seed values,
    positive count and the paired t test (empty without a pair)."""
    bs = {r["seed"]: r for r in b}
    diffs = []
    for r in a:
        if r["seed"] in bs:
            x, y = _value(r, k, subset), _value(bs[r["seed"]], k, subset)
            if x is not None and y is not None:
                diffs.append(x - y)
    if not diffs:
        return {}
    mean, std = _mean_std(diffs)
    return {"mean": mean, "std": std, "values": diffs, "positive": sum(d > 0 for d in diffs),
            **_paired_t(diffs)}


PAIRS = {
    "paired_vs_no_lidar": [(m, "no_lidar") for m in ("full", "geom_only", "zero", "learnable",
                                                     *WARP_ROWS, *EXTRA_ROWS)],
    "paired_warp": [("warp", "full"), ("full_warp", "full"), ("full_warp", "warp"),
                    ("warp_anchor", "warp"), ("warp_x", "warp"), ("no_lidar_x", "no_lidar"),
                    ("warp_anchor_x", "warp_x")],
    "paired_x_loss": [("warp_x", "no_lidar_x")],
    "paired_vs_zero": [(m, "zero") for m in ("full", "geom_only", "learnable")],
    "paired_vs_learnable": [(m, "learnable") for m in ("full", "geom_only")],
    "paired_training": [("freeze_full", "freeze_no_lidar"), ("finetune_full", "full"),
                        ("finetune_full_lr1e-4", "full"),
                        ("finetune_full_lr1e-4", "finetune_full"),
                        ("freeze_full", "full"), ("full_all_views", "full"),
                        ("full_no_dropout", "full")],
    "paired_time": [("full", "full_no_dtau"), ("offset_full", "offset_full_no_dtau"),
                    ("offset_full", "full")],
}
"""The paired tables: (a, b) rows, a - b in dB."""


def aggregate_paper(runs: list[dict[str, Any]], ks: tuple[int | str, ...] = (1, 10)
                    ) -> dict[str, Any]:
    """The suite's keys: per variant psnr_k<K>_<name>(_std) overall, on the hard subset and
    on large |delta tau| (with SSIM, margins and the reprojection consistency reproj_err,
    top level reproj_err_k<K>_<name>); baselines (psnr_<b>, and psnr_k<K>_<b> on the targets
    scored at K; reproj_err_<b> of the consistency candidates); the paired tables (by seed:
    rows against rows, and rows against each baseline on the same targets) and the headline
    effects freeze_lidar_gain_db and dtau_channel_effect_db (with _std)."""
    names = list(dict.fromkeys(r["variant"] for r in runs))
    by = {n: sorted((r for r in runs if r["variant"] == n), key=lambda r: r["seed"])
          for n in names}
    out: dict[str, Any] = {"rows": {}}
    for n, rs in by.items():
        row: dict[str, Any] = {"seeds": [r["seed"] for r in rs],
                               "train_minutes": statistics.fmean(r["train_minutes"] for r in rs)}
        if all("cpu_minutes" in r for r in rs):
            row["cpu_minutes"] = sum(r["cpu_minutes"] for r in rs)  # every seed together
        if all("val_loss" in r for r in rs):  # validation recordings: where choices are made
            row["val_loss"], row["val_loss_std"] = _mean_std([r["val_loss"] for r in rs])
        for k in ks:
            for subset, tag in (("all", ""), ("hard", "_hard"), ("large_dtau", "_dtau")):
                for metric, short in (("psnr_mean", "psnr"), ("ssim_mean", "ssim"),
                                      ("margin_db", "margin_db"), ("reproj_err", "reproj_err")):
                    xs = [x for r in rs if (x := _value(r, k, subset, metric)) is not None]
                    if xs:
                        row[f"{short}_k{k}{tag}"], row[f"{short}_k{k}{tag}_std"] = _mean_std(xs)
            temps = [r[f"eval_k{k}"]["temperature"] for r in rs
                     if "temperature" in r.get(f"eval_k{k}", {})]
            if temps:  # the validation recordings' pick, per seed
                row[f"temperature_k{k}"] = temps
        out["rows"][n] = row
        for k in ks:
            if f"psnr_k{k}" in row:
                out[f"psnr_k{k}_{n}"] = row[f"psnr_k{k}"]
                out[f"psnr_k{k}_{n}_std"] = row[f"psnr_k{k}_std"]
            if f"reproj_err_k{k}" in row:
                out[f"reproj_err_k{k}_{n}"] = row[f"reproj_err_k{k}"]
                out[f"reproj_err_k{k}_{n}_std"] = row[f"reproj_err_k{k}_std"]
    first = runs[0]
    out["baselines"] = {
        subset: dict(first["eval_k1"][subset].get("baselines", {}))
        for subset in ("all", "hard", "large_dtau") if subset in first["eval_k1"]}
    for b, v in out["baselines"].get("all", {}).items():
        out[f"psnr_{b}"], out[f"ssim_{b}"] = v["psnr_mean"], v["ssim_mean"]
    for k in ks:
        for b, v in first.get(f"eval_k{k}", {}).get("all", {}).get("baselines", {}).items():
            out[f"psnr_k{k}_{b}"], out[f"ssim_k{k}_{b}"] = v["psnr_mean"], v["ssim_mean"]
    out |= reproj_baselines(first["eval_k1"]["all"])
    out["paired_vs_baselines"] = baseline_pairs(by, ks)
    out["strongest_baseline"] = first["eval_k1"]["all"].get("better_baseline")
    if "psnr_reprojection" in out and "psnr_copy_source" in out:
        out["reprojection_margin_db"] = out["psnr_reprojection"] - out["psnr_copy_source"]
    out["hard_cut_m"] = first["eval_k1"]["hard_cut_m"]
    out["dtau_cut_s"] = first["eval_k1"]["dtau_cut_s"]
    for table, pairs in PAIRS.items():
        out[table] = {f"{a} - {b}": {f"psnr_k{k}{tag}": p for k in ks
                                     for subset, tag in (("all", ""), ("hard", "_hard"),
                                                         ("large_dtau", "_dtau"))
                                     if (p := paired(by[a], by[b], k, subset))}
                      for a, b in pairs if a in by and b in by}
    for key, (a, b, subset) in {"freeze_lidar_gain_db": ("freeze_full", "freeze_no_lidar", "all"),
                                "freeze_lidar_gain_hard_db": ("freeze_full", "freeze_no_lidar",
                                                              "hard"),
                                "dtau_channel_effect_db": ("full", "full_no_dtau", "large_dtau"),
                                "dtau_channel_effect_offset_db": ("offset_full",
                                                                  "offset_full_no_dtau",
                                                                  "large_dtau"),
                                "clock_offset_effect_db": ("offset_full", "full",
                                                           "large_dtau")}.items():
        if a in by and b in by and (p := paired(by[a], by[b], 1, subset)):
            out[key], out[f"{key}_std"], out[f"{key}_pairs"] = p["mean"], p["std"], len(
                p["values"])
    return out


def baseline_pairs(by: dict[str, list[dict[str, Any]]], ks: tuple[int | str, ...]
                   ) -> dict[str, Any]:
    """Per row and baseline, PSNR of the row minus the baseline on the same targets, paired
    by seed at each K (`paired` statistics): "<row> - <baseline>" -> psnr_k<K>."""
    out: dict[str, Any] = {}
    for name, rs in by.items():
        for b in rs[0]["eval_k1"]["all"].get("baselines", {}):
            as_row = [{"seed": r["seed"], **{f"eval_k{k}": {"all": {
                "psnr_mean": r[f"eval_k{k}"]["all"]["baselines"][b]["psnr_mean"]}}
                for k in ks if f"eval_k{k}" in r}} for r in rs]
            table = {f"psnr_k{k}": p for k in ks if (p := paired(rs, as_row, k))}
            if table:
                out[f"{name} - {b}"] = table
    return out


PAPER_HEADLINE = (*(f"psnr_k{k}_{m}" for k in (1, 10, label(10))
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
