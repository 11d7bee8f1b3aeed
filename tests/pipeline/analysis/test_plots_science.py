"""Science plots: every bar, error bar, seed dot and baseline inside the axes; each baseline
line drawn from the targets its plot's points are scored on."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import pytest

from pipeline.analysis.plots_science import (
    axis_limits,
    modes_figure,
    plot_paper,
    plot_reproj,
    plot_trade,
    reproj_modes,
)


def _result(k10: float) -> dict[str, Any]:
    """A science.json-like result whose K = 10 scores lie `k10` dB (far) below the baselines."""
    runs = [{"mode": m, "seed": s, "eval_k1": {"psnr_mean": 19.0 + s, "targets": 48},
             "eval_k10": {"psnr_mean": k10 + s, "targets": 48}}
            for m in ("full", "no_lidar") for s in (0, 1)]
    out: dict[str, Any] = {"runs": runs, "psnr_copy_source": 20.7, "psnr_mean_latent": 19.5}
    for m in ("full", "no_lidar"):
        out |= {f"psnr_{m}_k1": 19.5, f"psnr_{m}_k1_std": 0.7, f"psnr_{m}_k10": k10 + 0.5,
                f"psnr_{m}_k10_std": 0.7}
    return out


@pytest.mark.parametrize("k10", [12.0, 19.0, 25.0])
def test_the_y_axis_holds_every_bar_error_bar_dot_and_baseline(k10: float) -> None:
    fig = modes_figure(_result(k10))
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    data = [k10 + 0.5 - 0.7, k10 + 0.5 + 0.7, k10, k10 + 1, 20.7, 19.5, 19.5 - 0.7, 20.0 + 0.7]
    assert lo < min(data) and hi > max(data)
    for bar in ax.patches:  # the bars start at 0: their tops are what must show
        assert lo < bar.get_height() < hi
    labels = ax.get_legend_handles_labels()[1]
    assert "copy_source (48 targets)" in labels


def test_axis_limits_pad_equal_values() -> None:
    assert axis_limits([3.0, 3.0]) == (2.0, 4.0)
    lo, hi = axis_limits([0.0, 10.0])
    assert (lo, hi) == (-0.5, 10.5)


def test_trade_baselines_come_from_the_trade_rows_only(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib.axes

    rows = [{"K": k, "tol": None, "guidance": 1.0, "psnr": 18 + k / 10, "ssim": 0.5,
             "seconds_per_target": 0.1 * k, "targets": 16, "psnr_copy_source": 18.4}
            for k in (1, 10)]
    result = {"psnr_copy_source": 20.7, "ssim_copy_source": 0.6}  # another target set
    seen: list[tuple[float, str]] = []
    original = matplotlib.axes.Axes.axhline

    def spy(self: Any, y: float = 0, *args: Any, **kwargs: Any) -> Any:
        seen.append((y, kwargs.get("label", "")))
        return original(self, y, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "axhline", spy)
    assert plot_trade(rows, result, tmp_path / "trade.png").stat().st_size > 0
    # the rows' own copy-source PSNR, labelled with their targets; no SSIM line (the rows
    # carry none), never the 20.7 / 0.6 of the other target set
    assert seen == [(18.4, "copy_source (16 targets)")]


def test_reprojection_plot_only_for_modes_with_the_consistency(tmp_path: Path) -> None:
    result = {**_result(19.0), "reproj_err_full_k1": 0.6, "reproj_err_full_k10": 0.5,
              "reproj_err_full_k10_std": 0.05, "reproj_err_no_lidar_k1": 0.8,
              "reproj_err_ground_truth": 0.3, "reproj_err_copy_source": 0.9,
              "reproj_targets": 40}
    assert reproj_modes(result) == ["full"]  # no_lidar lacks K = 10
    assert plot_reproj(result, tmp_path / "r.png").stat().st_size > 5_000
    assert reproj_modes(_result(19.0)) == []


def _paper_result(with_m: bool) -> dict[str, Any]:
    rows = {n: {"psnr_k1": 15.0 + i, "psnr_k1_std": 0.1, "psnr_k1_hard": 14.5 + i,
                "psnr_k10": 14.0 + i, "psnr_k10_std": 0.2, "psnr_k10_hard": 13.5 + i}
            for i, n in enumerate(("no_lidar", "warp"))}
    out: dict[str, Any] = {"rows": rows, "baselines": {"all": {"copy_source": {
        "psnr_mean": 15.5, "ssim_mean": 0.2}}}}
    if with_m:
        out["psnr_by_m"] = {"2": {"1": {"psnr": 15.0, "wall_seconds_per_target": 0.1},
                                  "10": {"psnr": 14.0, "wall_seconds_per_target": 0.5}}}
    return out


def test_the_figure_is_drawn_with_and_without_the_m_target_table(tmp_path: Path) -> None:
    for with_m in (True, False):
        path = plot_paper(_paper_result(with_m), tmp_path / f"m{with_m}" / "science_paper.png")
        img = cv2.imread(str(path))
        assert img is not None and img.shape[:2] == (450, 1300)


def test_rows_with_tempered_scores_get_their_panels(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib.axes

    result = _paper_result(False)
    result["rows"]["warp"] |= {"psnr_k10_tval": 16.2, "psnr_k10_tval_std": 0.3,
                               "psnr_k1_tval": 16.3}
    titles: list[str] = []
    original = matplotlib.axes.Axes.set

    def spy(self: Any, **kwargs: Any) -> Any:
        titles.append(kwargs.get("title", ""))
        return original(self, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "set", spy)
    img = cv2.imread(str(plot_paper(result, tmp_path / "t.png")))
    assert img is not None and img.shape[:2] == (450, 1300)
    assert [t for t in titles if t] == ["K = 1", "K = 10", "K = 1, T chosen on validation",
                                        "K = 10, T chosen on validation"]
