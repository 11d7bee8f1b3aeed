"""Science bench: the aggregation over seeds (paired LiDAR effect, margins) and, marked slow,
the --quick end-to-end run through the real pipeline."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from bench.science import HEADLINE, QUICK, aggregate, run_science


def _run(mode: str, seed: int, k1: float, k10: float, val: float) -> dict[str, Any]:
    base = {"copy_source": {"psnr_mean": 19.0, "ssim_mean": 0.3},
            "mean_latent": {"psnr_mean": 17.0, "ssim_mean": 0.4}}
    return {"mode": mode, "seed": seed, "val_loss": val, "train_minutes": 2.0,
            "eval_loss": {"mean": val + 0.5},
            "eval_k1": {"psnr_mean": k1, "ssim_mean": 0.3, "baselines": base},
            "eval_k10": {"psnr_mean": k10, "ssim_mean": 0.2, "baselines": base}}


def test_aggregate_pairs_seeds_and_measures_margin_against_the_better_baseline() -> None:
    runs = [_run("full", 0, 20.0, 19.5, 1.0), _run("full", 1, 21.0, 19.7, 1.1),
            _run("no_lidar", 0, 19.0, 19.0, 1.3), _run("no_lidar", 1, 20.6, 19.1, 1.2),
            _run("geom_only", 0, 19.5, 19.2, 1.2), _run("zero", 0, 19.2, 19.1, 1.25)]
    out = aggregate(runs)
    assert out["psnr_model_k1"] == pytest.approx(20.5)
    assert out["psnr_model_k10"] == pytest.approx(19.6)
    assert out["psnr_model_k10_std"] == pytest.approx(math.sqrt(0.02))
    assert out["psnr_copy_source"] == 19.0 and out["psnr_mean_latent"] == 17.0
    assert out["model_margin_db"] == pytest.approx(0.6)  # K = 10 minus copy-source
    assert out["lidar_effect_db"] == pytest.approx(0.7)  # mean of paired diffs 1.0 and 0.4
    assert out["lidar_effect_db_std"] == pytest.approx(math.sqrt(0.18))
    assert out["lidar_effect_pairs"] == 2
    assert out["val_loss_full"] == pytest.approx(1.05)
    assert out["val_loss_no_lidar"] == pytest.approx(1.25)
    assert out["runs_per_mode"] == {"full": 2, "geom_only": 1, "zero": 1, "learnable": 0,
                                    "no_lidar": 2, "warp": 0, "full_warp": 0}
    assert out["eval_loss_full"] == pytest.approx(1.55)
    assert out["eval_loss_no_lidar_std"] == pytest.approx(math.sqrt(0.005))
    paired = out["paired_vs_no_lidar"]
    assert set(paired) == {"full", "geom_only", "zero"}
    assert paired["full"]["psnr_k10"]["values"] == pytest.approx([0.5, 0.6])
    assert paired["full"]["eval_loss_gain"]["values"] == pytest.approx([0.3, 0.1])
    # t = mean / (std / sqrt(n)) = 0.55 / (0.0707 / 1.414) = 11; two-sided p with 1 dof
    assert paired["full"]["psnr_k10"]["t"] == pytest.approx(11.0)
    assert paired["full"]["psnr_k10"]["p"] == pytest.approx(2 * (0.5 - math.atan(11) / math.pi))
    assert paired["geom_only"]["psnr_k1"] == {"mean": 0.5, "std": 0.0, "values": [0.5],
                                              "positive": 1}  # seed 0 only
    assert paired["zero"]["eval_loss_gain"]["positive"] == 1
    content = out["paired_vs_zero"]  # same adapter pathway: what the packets' content adds
    assert set(content) == {"full", "geom_only"}
    assert content["full"]["psnr_k1"]["values"] == pytest.approx([0.8])  # 20.0 - 19.2, seed 0


def test_margins_are_against_the_strongest_fair_baseline_in_each_metric() -> None:
    """The per-pixel mean training image can be the bar in PSNR while the mean latent is
    in SSIM; the held-out-view oracle never is."""
    runs = [_run("full", 0, 20.0, 19.5, 1.0), _run("no_lidar", 0, 19.0, 19.0, 1.3)]
    for r in runs:
        for k in (1, 10):
            r[f"eval_k{k}"]["baselines"] = {
                **r[f"eval_k{k}"]["baselines"],
                "mean_image": {"psnr_mean": 19.8, "ssim_mean": 0.35},
                "recording_mean_oracle": {"psnr_mean": 25.0, "ssim_mean": 0.9}}
    out = aggregate(runs)
    assert out["psnr_mean_image"] == 19.8 and out["ssim_mean_image"] == 0.35
    assert out["strongest_baseline"] == "mean_image"
    assert out["model_margin_db"] == pytest.approx(-0.3)  # K = 10 trails the mean image
    assert out["model_margin_db_k1"] == pytest.approx(0.2)
    assert out["strongest_ssim_baseline"] == "mean_latent"
    assert out["model_ssim_margin_k1"] == pytest.approx(-0.1)
    assert out["model_ssim_margin"] == pytest.approx(-0.2)


def test_aggregate_accepts_runs_measured_before_the_eval_loss() -> None:
    runs = [_run("full", 0, 20.0, 19.5, 1.0), _run("no_lidar", 0, 19.0, 19.0, 1.3)]
    for r in runs:
        del r["eval_loss"]
    out = aggregate(runs)
    assert "eval_loss_full" not in out
    assert set(out["paired_vs_no_lidar"]["full"]) == {"psnr_k1", "psnr_k10"}


@pytest.mark.slow
def test_quick_science_bench_end_to_end(tmp_path: Path) -> None:
    from dags.graph import STAGES

    out = run_science(QUICK, tmp_path, STAGES)
    for key in HEADLINE:
        assert key in out, key
    for key in ("psnr_model_k1", "psnr_model_k10", "psnr_copy_source", "psnr_mean_latent"):
        assert math.isfinite(out[key]) and 5.0 < out[key] < 60.0
    assert out["lidar_effect_pairs"] == 1
    assert len(out["speed_accuracy"]) == 3 * (5 + 3)  # guidance x (fixed K + adaptive tols)
    assert all(Path(p).stat().st_size > 0 for p in out["plots"])
    assert (tmp_path / "science.json").exists()
    again = run_science(QUICK, tmp_path, STAGES, train_missing=False)  # reuses every finished run
    assert again["psnr_model_k1"] == out["psnr_model_k1"]


def test_m3gd_plot_draws_the_science_result(tmp_path: Path) -> None:
    from pipeline.analysis.figures import make_plots, save_bench

    runs = [{**_run(m, 0, 20.0, 19.0, 1.0), "train_loss": [3.0, 2.0, 1.5, 1.2] * 10,
             "val_curve": [{"step": 20, "val_loss": 1.4}, {"step": 40, "val_loss": 1.2}]}
            for m in ("full", "no_lidar")]
    trade = [{"sampler": f"K={k}", "K": k, "tol": None, "guidance": s, "psnr": 18.0 + k / 10,
              "ssim": 0.3, "seconds_per_target": 0.01 * k, "targets": 8}
             for s in (1.0, 1.5) for k in (1, 2, 5)]
    trade.append({**trade[0], "sampler": "adaptive tol=0.01", "K": 5, "tol": 0.01})
    save_bench(tmp_path, "science", {**aggregate(runs), "runs": runs, "speed_accuracy": trade})
    names = {p.name for p in make_plots(tmp_path)}
    assert {"science_loss.png", "science_trade.png", "science_modes.png"} <= names
    assert all((tmp_path / "plots" / n).stat().st_size > 10_000
               for n in ("science_loss.png", "science_trade.png", "science_modes.png"))
