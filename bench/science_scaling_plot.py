"""The data-scaling figure: warp_x minus the strongest baseline and full minus no_lidar (dB)
against training recordings, at each K, with the spread over seeds as error bars
(`bench.science_scaling.scaling_table`'s "series")."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def plot_scaling(table: dict[str, Any], path: Path) -> Path:
    """Two panels (one per difference), a line per K (mean ± std over seeds; a point of one
    seed has no bar), recordings on a log-2 axis; the zero line dashed. Writes `path` (PNG,
    matplotlib Agg) and returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series: dict[str, dict[str, list[list[float]]]] = table.get("series", {})
    names = list(series) or ["(no finished point)"]
    fig, axes = plt.subplots(1, len(names), figsize=(5.2 * len(names), 3.8), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        for k, pts in series.get(name, {}).items():
            xs = [p[0] for p in pts]
            ax.errorbar(xs, [p[1] for p in pts], yerr=[p[2] if p[3] > 1 else 0.0 for p in pts],
                        marker="o", capsize=3, label=f"K = {k.replace('_tval', ', T val')}")
            for x, p in zip(xs, pts, strict=True):
                ax.annotate(f"{int(p[3])}s", (x, p[1]), textcoords="offset points",
                            xytext=(4, -10), fontsize=7)
        ax.axhline(0.0, color="grey", linestyle="--", linewidth=0.8)
        ax.set_xscale("log", base=2)
        ax.set_xlabel("training recordings")
        ax.set_ylabel(f"{name} (dB)")
        ax.set_title(name, fontsize=10)
        if series.get(name):
            ax.legend(fontsize=8)
    fig.suptitle("paper-cpu suite, held-out recordings of unseen seeds (n s: seeds)",
                 fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
