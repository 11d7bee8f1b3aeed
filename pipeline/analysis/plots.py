"""PNG figures for analysts (`m3gd plot`): Delta-tau, occupancy, depth, PCA colour, speed-accuracy.

Every function takes arrays or pyarrow tables and an output path, draws with matplotlib's Agg
renderer on a standalone `Figure` (no pyplot global state, safe in worker processes), writes one
PNG of exactly `figsize * DPI` pixels and returns the path. The numbers behind each figure come
from `pipeline.analysis.plot_data`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyarrow as pa
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pipeline.analysis.plot_data import (
    Records,
    as_rows,
    dtau_groups,
    occupancy_frequency,
    pca_rgb,
    series_by,
)
from schemas.errors import DataError

DPI: int = 100
"""Dots per inch of every PNG, so a (w, h) inch figure is (100 w, 100 h) pixels."""


def _save(fig: Figure, out: Path | str) -> Path:
    """Write `fig` as PNG to `out` (parents created) and return the path."""
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, format="png", dpi=DPI)
    return path


def _grid(n: int, size: tuple[float, float], ncols: int = 3) -> tuple[Figure, list[Axes]]:
    """Figure with n panels in rows of ncols, each panel `size` inches; extra panels hidden."""
    cols = max(1, min(ncols, n))
    rows = max(1, -(-n // cols))
    fig = Figure(figsize=(size[0] * cols, size[1] * rows), dpi=DPI, layout="constrained")
    axes = list(np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel())
    for ax in axes[n:]:
        ax.set_axis_off()
    return fig, axes


def plot_dtau_histograms(views: pa.Table, out: Path | str, bins: int = 40,
                         bound_s: float | None = None) -> Path:
    """Histogram of Delta-tau (sweep minus image stamp, ms) per (recording, camera).

    views: per-view stats table with columns recording, camera, dtau_s (float64 s, nullable)
    and, when present, reject_reason: accepted views (blue) and rejected ones (red) are drawn
    as separate histograms on shared bins. bound_s: the |Δτ| bound, drawn as dashed lines at
    +-bound. One panel per (recording, camera); an empty table gives one panel saying so.
    """
    groups = dtau_groups(views)
    ok, bad = dtau_groups(views, accepted=True), dtau_groups(views, accepted=False)
    fig, axes = _grid(max(1, len(groups)), (4.0, 3.0))
    if not groups:
        axes[0].text(0.5, 0.5, "no views with a sweep", ha="center", va="center")
    empty = np.zeros(0)
    for ax, ((rec, cam), dtau) in zip(axes, groups.items(), strict=False):
        edges = np.histogram_bin_edges(dtau * 1e3, bins=bins)
        a, r = ok.get((rec, cam), empty), bad.get((rec, cam), empty)
        ax.hist(a * 1e3, bins=edges.tolist(), color="tab:blue", label=f"accepted ({a.size})")
        if r.size:
            ax.hist(r * 1e3, bins=edges.tolist(), color="tab:red", label=f"rejected ({r.size})")
        if bound_s is not None:
            for x in (-bound_s * 1e3, bound_s * 1e3):
                ax.axvline(x, color="k", linestyle="--", linewidth=1)
        ax.set_title(f"{rec} / {cam} (n={dtau.size})", fontsize=9)
        ax.set_xlabel("Δτ [ms]")
        ax.set_ylabel("views")
        ax.legend(fontsize=7)
    return _save(fig, out)


def plot_error_vs_dtau(abs_dtau_s: npt.ArrayLike, abs_rel: npt.ArrayLike, out: Path | str
                       ) -> Path:
    """Scatter of per-view mean depth abs-rel against |Δτ| (ms), with the per-bin median."""
    x = np.asarray(abs_dtau_s, dtype=np.float64) * 1e3
    y = np.asarray(abs_rel, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    fig = Figure(figsize=(6.0, 4.0), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    ax.scatter(x[ok], y[ok], s=6, alpha=0.5, color="tab:blue", label="view")
    if ok.sum() >= 2:
        edges = np.linspace(x[ok].min(), x[ok].max() + 1e-9, 9)
        b = np.digitize(x[ok], edges) - 1
        mids = [(edges[i] + edges[i + 1]) / 2 for i in range(8) if np.any(b == i)]
        meds = [float(np.median(y[ok][b == i])) for i in range(8) if np.any(b == i)]
        ax.plot(mids, meds, color="tab:red", marker="o", label="bin median")
        ax.legend()
    ax.set_xlabel("|Δτ| [ms]")
    ax.set_ylabel("mean depth abs-rel of the view")
    ax.set_title(f"packet depth vs ground truth (views={int(ok.sum())})")
    return _save(fig, out)


def plot_error_map(cells: pa.Table, out: Path | str, title: str) -> Path:
    """Per-cell depth abs-rel of one view on its latent grid (rows row, col, abs_rel, border).

    Cells without a packet or a reference are blank; border cells (a depth discontinuity in
    the cell) are outlined in cyan; a legend under the map says so.
    """
    from matplotlib.patches import Patch

    rows = cells["row"].to_numpy().astype(np.int64)
    cols = cells["col"].to_numpy().astype(np.int64)
    err = cells["abs_rel"].to_numpy(zero_copy_only=False).astype(np.float64)
    border = cells["border"].to_numpy(zero_copy_only=False).astype(bool)
    h, w = (int(rows.max()) + 1, int(cols.max()) + 1) if rows.size else (1, 1)
    grid = np.full((h, w), np.nan)
    grid[rows, cols] = err
    fig = Figure(figsize=(7.0, 4.5), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    finite = err[np.isfinite(err)]
    vmax = float(np.percentile(finite, 95)) if finite.size else 1.0
    im = ax.imshow(grid, cmap="magma", vmin=0.0, vmax=max(vmax, 1e-6), interpolation="nearest")
    ax.scatter(cols[border], rows[border], marker="s", s=40, facecolors="none",
               edgecolors="cyan", linewidths=0.8, label="border cell")
    fig.colorbar(im, ax=ax, label="|d - d*| / d*")
    handles = [*ax.get_legend_handles_labels()[0],
               Patch(facecolor="white", edgecolor="grey", label="no packet or no reference")]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2,
              fontsize=8, frameon=False)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("cell column")
    ax.set_ylabel("cell row")
    return _save(fig, out)


def plot_occupancy(freq: npt.ArrayLike, out: Path | str, title: str = "supported-cell frequency"
                   ) -> Path:
    """Heat map of an (H, W) occupancy frequency in [0, 1] (fraction of views with n_q > 0)."""
    f = np.asarray(freq, dtype=np.float64)
    if f.ndim != 2:
        raise DataError(f"occupancy must be (H, W), got shape {f.shape}")
    fig = Figure(figsize=(6.0, 4.5), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    im = ax.imshow(f, vmin=0.0, vmax=1.0, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="fraction of views")
    ax.set_title(title)
    ax.set_xlabel("cell column")
    ax.set_ylabel("cell row")
    return _save(fig, out)


def plot_occupancy_from_cells(cells: pa.Table, grid_hw: tuple[int, int], out: Path | str,
                              n_views: int | None = None) -> Path:
    """Occupancy heat map from a per-cell stats table (see `occupancy_frequency`)."""
    return plot_occupancy(occupancy_frequency(cells, grid_hw, n_views), out)


def plot_depth_histogram(depth_m: npt.ArrayLike, out: Path | str, bins: int = 60,
                         label: str = "depth") -> Path:
    """Histogram of depths in metres (non-finite values dropped), log-spaced bins when positive."""
    d = np.asarray(depth_m, dtype=np.float64).ravel()
    d = d[np.isfinite(d)]
    fig = Figure(figsize=(6.0, 4.0), dpi=DPI, layout="constrained")
    ax = fig.subplots()
    if d.size and d.min() > 0 and d.max() > d.min():
        ax.hist(d, bins=np.geomspace(d.min(), d.max(), bins + 1).tolist(), color="tab:green")
        ax.set_xscale("log")
    elif d.size:
        ax.hist(d, bins=bins, color="tab:green")
    else:
        ax.text(0.5, 0.5, "no depths", ha="center", va="center")
    ax.set_xlabel(f"{label} [m]")
    ax.set_ylabel("count")
    ax.set_title(f"{label} (n={d.size})")
    return _save(fig, out)


def plot_pca_side_by_side(image: npt.ArrayLike, latents: npt.ArrayLike, points: npt.ArrayLike,
                          mask: npt.ArrayLike, out: Path | str) -> Path:
    """Image | PCA colour of latents (C, H, W) | PCA colour of point features (C_u, H, W).

    image: (Hi, Wi, 3) uint8 RGB. mask: (H, W) bool supported cells; unsupported cells are black
    in both feature panels (see `pca_rgb`). Cells are shown as blocks over the image extent.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise DataError(f"image must be (H, W, 3), got shape {img.shape}")
    panels: list[tuple[str, Any]] = [
        ("image", img),
        ("image latent PCA", pca_rgb(latents, mask)),
        ("point feature PCA", pca_rgb(points, mask)),
    ]
    extent = (0.0, float(img.shape[1]), float(img.shape[0]), 0.0)
    fig = Figure(figsize=(12.0, 3.0), dpi=DPI, layout="constrained")
    for ax, (title, data) in zip(fig.subplots(1, 3), panels, strict=True):
        ax.imshow(data, extent=extent, interpolation="nearest")
        ax.set_title(title)
        ax.set_axis_off()
    return _save(fig, out)


def plot_speed_accuracy(records: Records, out: Path | str, latency: str = "latency_s",
                        quality: str | None = "psnr", steps: str = "K",
                        targets: str = "M") -> Path:
    """Latency vs Euler steps K, one line per target count M; beside it quality vs K.

    records: benchmark rows (Table or dicts) with numeric columns `steps`, `targets`, `latency`
    (seconds) and, if `quality` is not None, that quality column. Missing values are skipped.
    """
    rows = as_rows(records)
    panels = [(latency, f"{latency} [s]")] + ([] if quality is None else [(quality, quality)])
    fig = Figure(figsize=(5.0 * len(panels), 4.0), dpi=DPI, layout="constrained")
    axes = list(np.atleast_1d(fig.subplots(1, len(panels))))
    for ax, (key, ylabel) in zip(axes, panels, strict=True):
        for group, (x, y) in series_by(rows, targets, steps, key).items():
            ax.plot(x, y, marker="o", label=f"{targets}={group}")
        ax.set_xlabel(f"{steps} (Euler steps)")
        ax.set_ylabel(ylabel)
        if ax.get_legend_handles_labels()[0]:
            ax.legend()
    return _save(fig, out)


FEW_POINTS = 50
"""A training curve of this many logged steps or fewer draws a marker at each (a line through
two or three points is easy to miss; one point draws no line at all)."""


def _empty_note(ax: Axes, text: str) -> None:
    """Say in the panel why it holds no curve."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.35")


def plot_training(records: list[dict[str, Any]], out: Path | str, title: str = "") -> Path:
    """A training log (`model.train_log` records) in four panels against the update: loss
    (train lines; the t-binned validation loss of eval lines), grad norm and learning rate,
    updates per second, and the model's PSNR beside the baselines' (eval lines)."""
    train = [r for r in records if r.get("kind") == "train"]
    evals = [r for r in records if r.get("kind") == "eval"]
    fig = Figure(figsize=(10.0, 7.0), dpi=DPI, layout="constrained")
    (a_loss, a_grad), (a_rate, a_psnr) = fig.subplots(2, 2)
    step = [r["step"] for r in train]
    mark = "o" if len(train) <= FEW_POINTS else None  # a short run: every logged step a dot
    a_loss.plot(step, [r["loss"] for r in train], marker=mark, label="train loss")
    if evals:
        a_loss.plot([r["step"] for r in evals], [r["val_loss_mean"] for r in evals],
                    marker="o", label="held-out loss (t grid)")
    a_loss.set_yscale("log")
    a_grad.plot(step, [r["grad_norm"] for r in train], marker=mark, label="grad norm")
    a_lr = a_grad.twinx()
    a_lr.plot(step, [r["lr"] for r in train], color="tab:orange", marker=mark, label="lr")
    a_lr.set_ylabel("learning rate")
    a_rate.plot(step, [r["steps_per_s"] for r in train], marker=mark)
    a_rate.set_ylabel("updates / s")
    for key, label in (("psnr_model", "model"), ("psnr_copy_source", "copy nearest source"),
                       ("psnr_mean_latent", "mean latent")):
        pts = [(r["step"], r[key]) for r in evals if key in r]
        if pts:
            a_psnr.plot(*zip(*pts, strict=True), marker="o", label=label)
    a_psnr.set_ylabel("held-out PSNR [dB]")
    if not train:
        for ax in (a_loss, a_grad, a_rate):
            _empty_note(ax, "no training step logged")
    if not evals:
        _empty_note(a_psnr, "no held-out evaluation in this run\n(m3gd train --eval-every N)")
    for ax in (a_loss, a_grad, a_rate, a_psnr):
        ax.set_xlabel("update")
        if ax.get_legend_handles_labels()[0]:
            ax.legend()
    fig.suptitle(title)
    return _save(fig, out)


def plot_reprojection_consistency(data: dict[str, Any], out: Path | str) -> Path:
    """`m3gd align --consistency` per recording/camera (`plot_data.consistency_data`): the
    photometric error at the recorded calibration and at the estimate; the recovered clock
    offset, against the injected one where known (the y = x line: perfect recovery), else
    per camera; and the recovered rotation (roll, pitch, yaw), likewise."""
    labels = list(data["labels"])
    n = len(labels)
    if n == 0:
        raise DataError("reprojection consistency: no row to plot")
    fig = Figure(figsize=(15.0, 4.2), dpi=DPI, layout="constrained")
    a_err, a_off, a_rot = fig.subplots(1, 3)
    x = np.arange(n)
    a_err.bar(x - 0.2, data["before"], width=0.4, label="recorded calibration")
    a_err.bar(x + 0.2, data["after"], width=0.4, label="at the estimate")
    a_err.set(xticks=x, ylabel="photometric error (grey levels²)",
              title="error before / after")
    a_err.set_xticklabels(labels, rotation=30, ha="right", fontsize=7)
    a_err.legend(fontsize=7)
    _recovery(a_off, data["injected_offset_ms"][:, None], data["offset_ms"][:, None],
              labels, ("offset",), "clock offset (ms)")
    _recovery(a_rot, data["injected_rotation_deg"], data["rotation_deg"], labels,
              ("roll", "pitch", "yaw"), "rotation (deg)")
    return _save(fig, out)


def _recovery(ax: Axes, injected: npt.NDArray[np.float64], recovered: npt.NDArray[np.float64],
              labels: list[str], parts: tuple[str, ...], unit: str) -> None:
    """Recovered (N, P) against injected (N, P) where some injected value is known (y = x
    dashed), else the recovered values per row as grouped bars."""
    known = np.isfinite(injected) & np.isfinite(recovered)
    if known.any():
        for j, part in enumerate(parts):
            k = known[:, j]
            ax.scatter(injected[k, j], recovered[k, j], label=part, zorder=3)
        both = np.concatenate([injected[known], recovered[known]])
        lo, hi = float(both.min()), float(both.max())
        pad = max(0.1 * (hi - lo), 0.05 * max(abs(lo), abs(hi)), 1e-3)
        ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], "k--", lw=0.8, label="y = x")
        ax.set(xlabel=f"injected {unit}", ylabel=f"recovered {unit}",
               title=f"recovered vs injected {unit.split(' (')[0]}")
    else:
        x = np.arange(len(labels))
        w = 0.8 / len(parts)
        for j, part in enumerate(parts):
            ax.bar(x + (j - (len(parts) - 1) / 2) * w, np.nan_to_num(recovered[:, j]), width=w,
                   label=part)
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set(xticks=x, ylabel=f"recovered {unit}",
               title=f"recovered {unit.split(' (')[0]} (nothing injected known)")
        ax.set_xticklabels(labels, rotation=30, ha="right", fontsize=7)
    ax.legend(fontsize=7)
