"""Plots of `m3gd bench science` results (science.json): loss curves, PSNR per packet mode over
seeds, the speed-accuracy trade. Drawn by the bench and by `m3gd plot` from the saved JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from schemas.modes import PACKET_MODES as MODES

BASELINE_STYLES = (("copy_source", "--"), ("mean_latent", ":"), ("mean_image", "-."),
                   ("reprojection", (0, (1, 1))))
"""Baselines drawn as horizontal lines (the fair ones; the oracle is left out)."""


def plot_science(result: dict[str, Any], out_dir: Path) -> list[Path]:
    """Loss curves (training loss, validation loss per mode) and the speed-accuracy trade."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    fig = Figure(figsize=(10, 4), dpi=100, layout="constrained")
    ax_t, ax_v = fig.subplots(1, 2)
    for r in result["runs"]:
        tl = np.asarray(r["train_loss"])
        w = max(1, len(tl) // 50)
        smooth = np.convolve(tl, np.ones(w) / w, mode="valid")
        if r["mode"] == "full":
            ax_t.plot(np.arange(len(smooth)) + w, smooth, label=f"full seed {r['seed']}")
        steps = [p["step"] for p in r["val_curve"]]
        ax_v.plot(steps, [p["val_loss"] for p in r["val_curve"]], marker="o",
                  label=f"{r['mode']} s{r['seed']}")
    ax_t.set(xlabel="step", ylabel="training loss (moving mean)", yscale="log")
    ax_v.set(xlabel="step", ylabel="validation loss (fixed t-grid and noise)", yscale="log")
    ax_t.legend(fontsize=7)
    ax_v.legend(fontsize=6, ncol=2)
    FigureCanvasAgg(fig)
    fig.savefig(out_dir / "science_loss.png", format="png", dpi=100)
    written.append(out_dir / "science_loss.png")
    if result.get("speed_accuracy"):
        written.append(plot_trade(result["speed_accuracy"], result, out_dir / "science_trade.png"))
    written.append(plot_modes(result, out_dir / "science_modes.png"))
    if reproj_modes(result):
        written.append(plot_reproj(result, out_dir / "science_reproj.png"))
    return written


REPROJ_LINES = (("ground_truth", "-"), ("copy_source", "--"), ("mean_latent", ":"),
                ("reprojection", (0, (1, 1))))
"""Reprojection-consistency references drawn as horizontal lines (the truth is the floor)."""


def reproj_modes(result: dict[str, Any]) -> list[str]:
    """The packet modes whose runs all carry the reprojection consistency at K = 1 and 10."""
    return [m for m in MODES if all(f"reproj_err_{m}_k{k}" in result for k in (1, 10))]


def plot_reproj(result: dict[str, Any], out: Path) -> Path:
    """Reprojection consistency (RMS intensity in [0, 1], lower is more consistent with the
    LiDAR points) per packet mode at K = 1 and 10 (mean, error bar = std over seeds), the
    ground truth and the baselines on the same targets as lines; written to `out`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4), dpi=100, layout="constrained")
    ax = fig.subplots()
    modes = reproj_modes(result)
    for j, k in enumerate((1, 10)):
        xs = np.arange(len(modes)) + (j - 0.5) * 0.3
        ax.bar(xs, [result[f"reproj_err_{m}_k{k}"] for m in modes], width=0.3,
               yerr=[result.get(f"reproj_err_{m}_k{k}_std", 0.0) for m in modes], capsize=3,
               alpha=0.7, label=f"K = {k}")
    n = result.get("reproj_targets", "?")
    for name, style in REPROJ_LINES:
        if f"reproj_err_{name}" in result:
            ax.axhline(result[f"reproj_err_{name}"], color="grey", linestyle=style,
                       label=f"{name} ({n} targets)")
    ax.set(xticks=np.arange(len(modes)), xticklabels=modes, ylim=(0, None),
           ylabel="reprojection error (RMS intensity, 0-1)",
           title="consistency with the LiDAR points the target was conditioned on")
    ax.legend(fontsize=7)
    FigureCanvasAgg(fig)
    fig.savefig(out, format="png", dpi=100)
    return out


def plot_modes(result: dict[str, Any], out: Path) -> Path:
    """Held-out PSNR per packet mode at K = 1 and K = 10 (mean, error bar = std over seeds,
    dots = seeds), the two baselines as horizontal lines; written to `out`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = modes_figure(result)
    FigureCanvasAgg(fig)
    fig.savefig(out, format="png", dpi=100)
    return out


def modes_figure(result: dict[str, Any]) -> Any:
    """The figure of `plot_modes` (a matplotlib Figure); its y axis holds every bar, error
    bar, seed dot and baseline."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4), dpi=100, layout="constrained")
    ax = fig.subplots()
    modes = [m for m in MODES if any(r["mode"] == m for r in result["runs"])]
    drawn: list[float] = []
    for j, k in enumerate((1, 10)):
        xs = np.arange(len(modes)) + (j - 0.5) * 0.3
        vals = [[r[f"eval_k{k}"]["psnr_mean"] for r in result["runs"] if r["mode"] == m]
                for m in modes]
        means = [result[f"psnr_{m}_k{k}"] for m in modes]
        stds = [result[f"psnr_{m}_k{k}_std"] for m in modes]
        ax.bar(xs, means, width=0.3, label=f"K = {k}", yerr=stds, capsize=3, alpha=0.7)
        for x, v in zip(xs, vals, strict=True):
            ax.scatter([x] * len(v), v, color="black", s=8, zorder=3)
        drawn += [*(m - sd for m, sd in zip(means, stds, strict=True)),
                  *(m + sd for m, sd in zip(means, stds, strict=True)),
                  *(v for seeds in vals for v in seeds)]
    targets = _targets(result)
    for name, style in BASELINE_STYLES:
        if f"psnr_{name}" in result:
            ax.axhline(result[f"psnr_{name}"], color="grey", linestyle=style,
                       label=f"{name} ({targets})")
            drawn.append(result[f"psnr_{name}"])
    ax.set(xticks=np.arange(len(modes)), xticklabels=modes, ylabel="held-out PSNR dB",
           ylim=axis_limits(drawn), title="packet modes over seeds (error bar: std)")
    ax.legend(fontsize=7)
    return fig


def axis_limits(values: list[float], pad: float = 0.05) -> tuple[float, float]:
    """(low, high) that contain every value with `pad` of their range on each side (1 when all
    are equal): bars, error bars, dots and lines all inside the axes."""
    lo, hi = min(values), max(values)
    margin = pad * (hi - lo) if hi > lo else 1.0
    return lo - margin, hi + margin


def _targets(result: dict[str, Any]) -> str:
    """'N targets' the per-mode scores and baselines are over (the runs' eval targets)."""
    counts = {r.get("eval_k10", {}).get("targets") for r in result["runs"]}
    counts.discard(None)
    return f"{counts.pop()} targets" if len(counts) == 1 else "eval targets"


def plot_trade(rows: list[dict[str, Any]], result: dict[str, Any], out: Path) -> Path:
    """PSNR and SSIM against seconds per target (wall seconds where the rows have them, else
    CPU seconds of one thread); one line per guidance, baselines dashed."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    wall = all("wall_seconds_per_target" in r for r in rows)
    sec = "wall_seconds_per_target" if wall else "seconds_per_target"
    xlabel = ("wall" if wall else "CPU") + " seconds per target (sample + decode + score, 1 thread)"
    fig = Figure(figsize=(10, 4), dpi=100, layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, key in zip(axes, ("psnr", "ssim"), strict=True):
        for s in sorted({r["guidance"] for r in rows}):
            fixed = [r for r in rows if r["guidance"] == s and r["tol"] is None]
            ada = [r for r in rows if r["guidance"] == s and r["tol"] is not None]
            line = ax.plot([r[sec] for r in fixed], [r[key] for r in fixed],
                           marker="o", label=f"fixed K, s={s:g}")[0]
            ax.scatter([r[sec] for r in ada], [r[key] for r in ada],
                       marker="x", color=line.get_color(), label=f"adaptive, s={s:g}")
            for r in fixed:
                ax.annotate(str(r["K"]), (r[sec], r[key]), fontsize=7)
        for name, style in BASELINE_STYLES:
            level = rows[0].get(f"{key}_{name}")  # on the trade's own targets, never others
            if level is not None:
                ax.axhline(level, color="grey", linestyle=style,
                           label=f"{name} ({rows[0].get('targets', '?')} targets)")
        ax.set(xlabel=xlabel,
               ylabel="PSNR dB" if key == "psnr" else "SSIM", xscale="log")
        ax.legend(fontsize=7)
    FigureCanvasAgg(fig)
    fig.savefig(out, format="png", dpi=100)
    return out


def plot_paper(result: dict[str, Any], out: Path) -> Path:
    """The paper suite (paper.json): PSNR per row over seeds at K = 1 (all targets and the
    hard subset, error bar = std, baselines as lines), and either PSNR and wall seconds per
    target against K for each number M of jointly synthesized targets or, without that table
    (`--rows`), the same bars at K = 10 (and at K = 1 and 10 with the validation-chosen
    sampler temperature, where the rows carry them)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 4.5), dpi=100, layout="constrained")
    by_m = result.get("psnr_by_m", {})
    if by_m:
        ax, ax_q, ax_t = fig.subplots(1, 3, width_ratios=(3, 1, 1))
        _row_bars(ax, result, 1)
        _m_panels(ax_q, ax_t, by_m)
    else:
        keys: list[int | str] = [1, 10, *(k for k in ("1_tval", "10_tval") if any(
            f"psnr_k{k}" in r for r in result["rows"].values()))]
        for a, k in zip(fig.subplots(1, len(keys)), keys, strict=True):
            _row_bars(a, result, k)
        fig.suptitle("held-out PSNR per row (error bar: std over seeds; T: the sampler's "
                     "temperature)", fontsize=10)
    FigureCanvasAgg(fig)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png", dpi=100)
    return out


def _row_bars(ax: Any, result: dict[str, Any], k: int | str) -> None:
    """PSNR at K = k per row of paper.json (all targets and the hard subset, std over seeds
    as error bars) with the baselines as horizontal lines; k "<K>_tval": K steps at the
    temperature the validation recordings chose."""
    rows = result["rows"]
    names = list(rows)
    for j, (tag, label) in enumerate((("", "all targets"), ("_hard", "hard subset"))):
        xs = np.arange(len(names)) + (j - 0.5) * 0.35
        ax.bar(xs, [rows[n].get(f"psnr_k{k}{tag}", np.nan) for n in names], width=0.35,
               yerr=[rows[n].get(f"psnr_k{k}{tag}_std", 0.0) for n in names], capsize=2,
               alpha=0.7, label=label)
    base = result.get("baselines", {}).get("all", {})
    for name, style in BASELINE_STYLES:
        if name in base:
            ax.axhline(base[name]["psnr_mean"], color="grey", linestyle=style, label=name)
    levels = [rows[n][f"psnr_k{k}"] for n in names if f"psnr_k{k}" in rows[n]]
    steps = str(k).removesuffix("_tval")
    sampler = f"K = {steps}" + (", T chosen on validation" if steps != str(k) else "")
    ax.set(xticks=np.arange(len(names)), ylabel="held-out PSNR dB",
           ylim=(min([*levels, *(b["psnr_mean"] for b in base.values())]) - 1.0, None),
           title=sampler)
    ax.set_xticklabels(names, rotation=40, ha="right", fontsize=7)
    ax.legend(fontsize=7)


def _m_panels(ax_q: Any, ax_t: Any, by_m: dict[str, Any]) -> None:
    """PSNR and wall seconds per target against K, one line per number M of targets."""
    for m, by_k in by_m.items():
        ks = sorted(by_k, key=int)
        ax_q.plot([int(k) for k in ks], [by_k[k]["psnr"] for k in ks], marker="o",
                  label=f"M = {m}")
        ax_t.plot([int(k) for k in ks], [by_k[k]["wall_seconds_per_target"] for k in ks],
                  marker="o", label=f"M = {m}")
    ax_q.set(xlabel="Euler steps K", ylabel="PSNR dB", xscale="log", title="M targets")
    ax_t.set(xlabel="Euler steps K", ylabel="wall s per target", xscale="log")
    ax_q.legend(fontsize=7)
    ax_t.legend(fontsize=7)
