"""The science bench's results: headline figures aggregated over seeds and its plots (pure
aggregation and matplotlib; the training and scoring are in bench.science)."""

from __future__ import annotations

import statistics
from collections.abc import Callable
from typing import Any

from model.evaluate import FAIR_BASELINES
from schemas.modes import MODEL_MODES as MODES


def _mean_std(xs: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value)."""
    return statistics.fmean(xs), (statistics.stdev(xs) if len(xs) > 1 else 0.0)


def aggregate(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The bench's headline keys (means over seeds with _std) from per-run results."""
    by = {m: sorted((r for r in runs if r["mode"] == m), key=lambda r: r["seed"])
          for m in MODES}
    out: dict[str, Any] = {}
    for m in (m for m in MODES if by[m]):
        out |= _mode_means(m, by[m])
    full = by["full"]
    for k in (1, 10):  # the model of the headline is the full-packet one
        out[f"psnr_model_k{k}"] = out[f"psnr_full_k{k}"]
        out[f"psnr_model_k{k}_std"] = out[f"psnr_full_k{k}_std"]
        out[f"ssim_model_k{k}"] = statistics.fmean(r[f"eval_k{k}"]["ssim_mean"] for r in full)
    out |= baseline_margins(full[0]["eval_k1"]["baselines"],  # same targets in every run
                            {k: (out[f"psnr_model_k{k}"], out[f"ssim_model_k{k}"])
                             for k in (1, 10)})
    out |= reproj_baselines(full[0]["eval_k1"])
    out["paired_vs_no_lidar"] = _paired_table(by)
    out["paired_vs_zero"] = _paired_table(by, "zero")
    effect = out["paired_vs_no_lidar"].get("full", {}).get("psnr_k1")  # paired by seed, K = 1
    out["lidar_effect_db"], out["lidar_effect_db_std"] = (
        (effect["mean"], effect["std"]) if effect else (0, 0))
    out["lidar_effect_pairs"] = len(effect["values"]) if effect else 0
    vdiff = _paired(by["no_lidar"], full, _val)
    out["lidar_val_loss_gain"], out["lidar_val_loss_gain_std"] = (
        _mean_std(vdiff) if vdiff else (0, 0))
    out["train_minutes"] = statistics.fmean(r["train_minutes"] for r in runs)
    out["runs_per_mode"] = {m: len(by[m]) for m in MODES}
    return out


def baseline_margins(base: dict[str, dict[str, float]],
                     model: dict[int, tuple[float, float]]) -> dict[str, Any]:
    """psnr_<baseline> and ssim_<baseline> of every baseline, the strongest fair one in each
    metric, and the model's margins over it: model_margin_db (K = 10) and model_margin_db_k1
    in PSNR, model_ssim_margin(_k1) in SSIM. model: K -> (PSNR, SSIM). Where the
    reprojection baseline was scored: its margins over copy-nearest-source
    (reprojection_margin_db, reprojection_ssim_margin) and the model's PSNR margins over it
    (model_margin_reprojection_db(_k1)); it is fair but geometric, so never the
    `strongest_baseline` (the bar among the non-geometric ones)."""
    out: dict[str, Any] = {}
    for n, v in base.items():
        out[f"psnr_{n}"], out[f"ssim_{n}"] = v["psnr_mean"], v["ssim_mean"]
    fair = [n for n in base if n in FAIR_BASELINES]
    best = max(fair, key=lambda n: base[n]["psnr_mean"])
    best_ssim = max(fair, key=lambda n: base[n]["ssim_mean"])
    out["strongest_baseline"], out["strongest_ssim_baseline"] = best, best_ssim
    for k, suffix in ((10, ""), (1, "_k1")):
        out[f"model_margin_db{suffix}"] = model[k][0] - base[best]["psnr_mean"]
        out[f"model_ssim_margin{suffix}"] = model[k][1] - base[best_ssim]["ssim_mean"]
    if "reprojection" in base and "copy_source" in base:
        rep, copy = base["reprojection"], base["copy_source"]
        out["reprojection_margin_db"] = rep["psnr_mean"] - copy["psnr_mean"]
        out["reprojection_ssim_margin"] = rep["ssim_mean"] - copy["ssim_mean"]
        for k, suffix in ((10, ""), (1, "_k1")):
            out[f"model_margin_reprojection_db{suffix}"] = model[k][0] - rep["psnr_mean"]
    return out


def reproj_baselines(score: dict[str, Any]) -> dict[str, Any]:
    """reproj_err_<name> of every non-model candidate of one run's scores (the same targets
    and cells in every run: they depend on the data only) and reproj_targets; {} when the
    run has no reprojection consistency."""
    if "reproj_err_baselines" not in score:
        return {}
    return {**{f"reproj_err_{n}": v for n, v in score["reproj_err_baselines"].items()},
            "reproj_targets": score["reproj_targets"]}


def _mode_means(mode: str, runs: list[dict[str, Any]]) -> dict[str, float]:
    """Mean and std over the seeds of one mode: validation loss, K = 1 and K = 10 PSNR, the
    eval t-grid loss when every run measured it (runs of older versions did not), and the
    reprojection consistency reproj_err_<mode>_k<K> when every run has it."""
    values = {f"val_loss_{mode}": [_val(r) for r in runs],
              **{f"psnr_{mode}_k{k}": [_psnr_k1(r) if k == 1 else _psnr_k10(r) for r in runs]
                 for k in (1, 10)}}
    if all("eval_loss" in r for r in runs):
        values[f"eval_loss_{mode}"] = [_eval(r) for r in runs]
    for k in (1, 10):
        if all("reproj_err" in r[f"eval_k{k}"] for r in runs):
            values[f"reproj_err_{mode}_k{k}"] = [float(r[f"eval_k{k}"]["reproj_err"])
                                                 for r in runs]
    out: dict[str, float] = {}
    for key, xs in values.items():
        out[key], out[f"{key}_std"] = _mean_std(xs)
    return out


def _psnr_k1(run: dict[str, Any]) -> float:
    return float(run["eval_k1"]["psnr_mean"])


def _psnr_k10(run: dict[str, Any]) -> float:
    return float(run["eval_k10"]["psnr_mean"])


def _val(run: dict[str, Any]) -> float:
    return float(run["val_loss"])


def _eval(run: dict[str, Any]) -> float:
    return float(run["eval_loss"]["mean"])


def _paired(a: list[dict[str, Any]], b: list[dict[str, Any]],
            value: Callable[[dict[str, Any]], float]) -> list[float]:
    """value(run of a) - value(run of b) for every seed both have, in seed order."""
    bs = {r["seed"]: r for r in b}
    return [value(r) - value(bs[r["seed"]]) for r in a if r["seed"] in bs]


def _paired_t(diffs: list[float]) -> dict[str, float]:
    """Paired t statistic of `diffs` and its two-sided p value (n - 1 degrees of freedom);
    empty for fewer than two pairs or no spread."""
    from scipy import stats

    if len(diffs) < 2 or statistics.stdev(diffs) == 0:
        return {}
    res = stats.ttest_1samp(diffs, 0.0)
    return {"t": float(res.statistic), "p": float(res.pvalue)}


def _paired_table(by: dict[str, list[dict[str, Any]]],
                  ref: str = "no_lidar") -> dict[str, dict[str, Any]]:
    """Per other mode with runs: the paired (same seed) difference to `ref` of K = 1 and
    K = 10 PSNR (dB, mode - ref) and of the eval t-grid loss (ref - mode, a gain), as mean,
    std, the per-seed values, how many pairs were positive and the paired t test.

    Against no_lidar a difference mixes what the packets say with the adapter's extra input
    pathway; against zero (the same pathway fed zeros) it is what their content adds."""
    base = by.get(ref, [])
    table: dict[str, dict[str, Any]] = {}
    for m in (m for m in MODES if m not in (ref, "no_lidar") and by.get(m)):
        row: dict[str, Any] = {}
        comparisons = [("psnr_k1", by[m], base, _psnr_k1), ("psnr_k10", by[m], base, _psnr_k10)]
        if all("eval_loss" in r for r in by[m] + base):  # runs of older versions lack it
            comparisons.append(("eval_loss_gain", base, by[m], _eval))
        for key, a, b, value in comparisons:
            diffs = _paired(a, b, value)
            if diffs:
                mean, std = _mean_std(diffs)
                row[key] = {"mean": mean, "std": std, "values": diffs,
                            "positive": sum(d > 0 for d in diffs), **_paired_t(diffs)}
        table[m] = row
    return table
