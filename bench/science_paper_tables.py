"""The paper suite's tables from its finished runs (pure: run dicts in, table dicts out).

A run is the JSON `bench.science_paper.run_variant` writes: per score key k (an int K, the
paper's sampler, or "<K>_tval", the validation-chosen temperature) an eval_k<k> dict with
the "all", "hard" and "large_dtau" subsets, each with psnr_mean, ssim_mean, margin_db,
reproj_err and the baselines scored on the same targets.
"""

from __future__ import annotations

import statistics
from typing import Any

from bench.science_paper_rows import EXTRA_ROWS, WARP_ROWS
from bench.science_report import _mean_std, _paired_t, reproj_baselines


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
