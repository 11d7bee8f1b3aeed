"""The data-scaling table: planning (points, synth seeds, evaluation seeds never trained on),
the table from fake run JSON (rows, baselines, differences and their spreads), the figure; and,
marked slow, a tiny point end to end through the real pipeline."""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Any

import pytest

from bench.science_paper import CPU_PAPER
from bench.science_scaling import (
    EVAL_SEEDS,
    ROWS,
    json_name,
    mission_names,
    scaling_suite,
    scaling_table,
    train_seeds,
)
from bench.science_scaling_plot import plot_scaling

BASE = {"copy_source": 15.0, "mean_latent": 16.0, "reprojection": 15.5, "mean_image": 15.7,
        "recording_mean_oracle": 17.0}


def _run(variant: str, seed: int, psnr: dict[int | str, float],
         base: dict[str, float] | None = None) -> dict[str, Any]:
    """A run's JSON as `run_variant` writes it, at the score keys of `psnr`."""
    b = base or BASE
    top = max((n for n in b if n != "recording_mean_oracle"), key=lambda n: b[n])
    run: dict[str, Any] = {"variant": variant, "seed": seed, "train_minutes": 1.0,
                           "cpu_minutes": 1.2, "val_loss": 1.0}
    for k, p in psnr.items():
        run[f"eval_k{k}"] = {"hard_cut_m": 1.0, "dtau_cut_s": 0.01, "all": {
            "psnr_mean": p, "ssim_mean": 0.2, "margin_db": p - b["mean_latent"],
            "baselines": {n: {"psnr_mean": v, "ssim_mean": 0.2} for n, v in b.items()},
            "strongest_baseline": top, "margin_strongest_db": p - b[top]}}
    return run


def test_train_seeds_skip_the_evaluation_seeds() -> None:
    assert train_seeds(8) == (0, 1)
    assert train_seeds(128) == (*range(20), *range(22, 34))
    assert not set(train_seeds(128)) & set(EVAL_SEEDS)
    assert len(mission_names(train_seeds(32))) == 32
    for bad in (6, 2, 0):
        with pytest.raises(ValueError, match="multiple of the 4 scenes"):
            train_seeds(bad)


def test_suite_plans_points_smallest_first_with_their_seeds() -> None:
    suite = scaling_suite([32, 8, 128], [3, 2, 1])
    assert [(n, len(s), t) for n, s, t in suite.points()] == [
        (8, 2, (0, 1)), (32, 8, (0, 1, 2)), (128, 32, (0,))]
    assert [v.name for v in suite.paper.variants] == ["full", "no_lidar", "warp_x"]
    assert suite.paper.preset.spec == CPU_PAPER.preset.spec  # network and steps fixed
    assert suite.data((0, 1)).synth_seeds == (0, 1, *EVAL_SEEDS)
    assert json_name(suite) == "scaling_8-32-128.json"
    assert scaling_suite([8]).seeds == (len(CPU_PAPER.preset.seeds),)
    with pytest.raises(ValueError, match="seeds per point"):
        scaling_suite([8, 32], [3])
    with pytest.raises(ValueError, match="unknown rows"):
        scaling_suite([8], rows=["warp", "wrap"])


def _point(shift: float, seeds: int, base: dict[str, float] | None = None
           ) -> list[dict[str, Any]]:
    """Runs of ROWS: no_lidar 15 + s/10, full 0.1 + 0.05 s above it, warp_x `shift` + s/5."""
    runs = []
    for s in range(seeds):
        nl = 15.0 + s / 10
        for name, p in (("no_lidar", nl), ("full", nl + 0.1 + 0.05 * s),
                        ("warp_x", 16.0 + shift + s / 5)):
            runs.append(_run(name, s, {1: p, 10: p - 1.0, "10_tval": p - 0.2}, base))
    return runs


def test_table_differences_and_spreads_are_computed_from_the_runs() -> None:
    big = dict(BASE, mean_latent=16.2)
    table = scaling_table({32: _point(0.5, 2, big), 8: _point(0.1, 3)}, (1, 10, "10_tval"))
    assert list(table["points"]) == ["8", "32"]
    p8 = table["points"]["8"]
    assert p8["baselines"] == BASE and p8["strongest_baseline"] == "mean_latent"
    w = p8["rows"]["warp_x"]
    assert w["psnr_k1"] == pytest.approx(16.1 + 0.2)
    assert w["psnr_k1_std"] == pytest.approx(statistics.stdev([16.1, 16.3, 16.5]))
    strong = p8["differences"]["warp_x - strongest"]["1"]
    assert strong["values"] == pytest.approx([0.1, 0.3, 0.5])
    assert strong["mean"] == pytest.approx(0.3) and strong["std"] == pytest.approx(0.2)
    assert strong["baseline"] == ["mean_latent"]
    assert p8["differences"]["warp_x - strongest"]["10"]["mean"] == pytest.approx(-0.7)
    lidar = p8["differences"]["full - no_lidar"]["1"]
    assert lidar["values"] == pytest.approx([0.1, 0.15, 0.2])  # paired by seed
    assert lidar["std"] == pytest.approx(0.05) and lidar["positive"] == 3
    p32 = table["points"]["32"]  # the strongest baseline of this point's own targets
    assert p32["differences"]["warp_x - strongest"]["1"]["values"] == pytest.approx([0.3, 0.5])
    series = table["series"]["warp_x - strongest"]["1"]
    assert [p[0] for p in series] == [8.0, 32.0] and [p[3] for p in series] == [3.0, 2.0]
    assert series[1][1] == pytest.approx(0.4)


def test_a_point_without_a_row_has_no_difference_of_it() -> None:
    runs = [r for r in _point(0.0, 2) if r["variant"] != "no_lidar"]
    table = scaling_table({8: runs, 32: []}, (1,))
    assert list(table["points"]) == ["8"]
    assert "full - no_lidar" not in table["points"]["8"]["differences"]
    assert "full - no_lidar" not in table["series"]
    one = table["points"]["8"]["differences"]["warp_x - strongest"]["1"]
    assert len(one["values"]) == 2 and not math.isnan(one["std"])


def test_plot_is_written(tmp_path: Path) -> None:
    table = scaling_table({8: _point(0.1, 3), 128: _point(0.4, 1)}, (1, 10))
    out = plot_scaling(table, tmp_path / "s.png")
    assert out.stat().st_size > 1000
    assert plot_scaling({}, tmp_path / "empty.png").is_file()


@pytest.mark.slow
def test_a_tiny_point_end_to_end(tmp_path: Path) -> None:
    """One seed, 4 training recordings, 4 held-out ones, a few steps: the table's keys."""
    from dataclasses import replace

    from bench.science_paper import QUICK_PAPER
    from bench.science_scaling import run_scaling
    from dags.graph import STAGES

    quick = replace(QUICK_PAPER, preset=replace(QUICK_PAPER.preset, data=replace(
        CPU_PAPER.preset.data, seconds=3.0, points_per_sweep=512), spec=replace(
        QUICK_PAPER.preset.spec, val_recordings=1, eval_clips=4, val_clips=4)))
    suite = replace(scaling_suite([4], [1], ROWS, quick), eval_seeds=(20,))
    result = run_scaling(suite, tmp_path, STAGES)
    point = result["points"]["4"]
    assert set(point["rows"]) == set(ROWS)
    assert set(point["differences"]) == {"warp_x - strongest", "full - no_lidar"}
    assert (tmp_path / "scaling_4.json").is_file() and Path(result["plot"]).is_file()
