"""The validation-chosen sampler temperature: the pick (ties to the colder), the suite's
score keys, and how runs with and without the tempered score aggregate."""

from __future__ import annotations

from typing import Any

import pytest

from bench.science_paper import CPU_PAPER, PAPER_HEADLINE
from bench.science_paper_tables import aggregate_paper
from bench.science_tempered import TEMPERATURES, Tempering, label, pick
from tests.bench.test_science_paper_tables import _run


def test_pick_takes_the_best_validation_psnr() -> None:
    assert pick({0.0: 16.1, 0.5: 16.3, 1.0: 15.2}) == 0.5


def test_pick_ties_go_to_the_lowest_temperature() -> None:
    assert pick({1.0: 16.0, 0.25: 16.0, 0.5: 15.0}) == 0.25


def test_pick_refuses_an_empty_grid() -> None:
    with pytest.raises(ValueError, match="no temperature scored"):
        pick({})


def test_the_grid_holds_the_papers_sampler_and_the_deterministic_one() -> None:
    assert 1.0 in TEMPERATURES and 0.0 in TEMPERATURES
    assert Tempering(ks=(5, 10)).labels() == ("5_tval", label(10))
    assert CPU_PAPER.score_keys() == (1, 10, "1_tval", "10_tval")
    assert "psnr_k10_tval_warp" in PAPER_HEADLINE


def _tempered(variant: str, seed: int, psnr: float, temperature: float) -> dict[str, Any]:
    run = _run(variant, seed, 15.0, 15.0, 15.0)
    part = dict(run["eval_k10"])
    part["all"] = {**part["all"], "psnr_mean": psnr}
    run["eval_k10_tval"] = {**part, "temperature": temperature,
                            "val_psnr": {"0.0": psnr, "1.0": psnr - 1}}
    return run


def test_tempered_scores_aggregate_and_pair_beside_the_papers_sampler() -> None:
    runs = [_tempered("warp", 0, 16.5, 0.0), _tempered("warp", 1, 16.9, 0.25),
            _tempered("no_lidar", 0, 15.5, 0.0), _tempered("no_lidar", 1, 15.7, 0.5)]
    out = aggregate_paper(runs, CPU_PAPER.score_keys())
    assert out["psnr_k10_tval_warp"] == pytest.approx(16.7)
    assert out["psnr_k10_warp"] == pytest.approx(15.0)  # the paper's sampler apart
    assert out["rows"]["warp"]["temperature_k10_tval"] == [0.0, 0.25]
    pair = out["paired_vs_no_lidar"]["warp - no_lidar"]["psnr_k10_tval"]
    assert pair["values"] == pytest.approx([1.0, 1.2])
    vs = out["paired_vs_baselines"]["warp - copy_source"]["psnr_k10_tval"]
    assert vs["values"] == pytest.approx([1.5, 1.9])  # copy_source scores 15.0 on the targets


def test_runs_scored_before_the_tempered_key_still_aggregate() -> None:
    runs = [_run("warp", 0, 16.0, 16.0, 16.0), _tempered("warp", 1, 16.9, 0.0)]
    out = aggregate_paper(runs, CPU_PAPER.score_keys())
    assert out["psnr_k10_tval_warp"] == pytest.approx(16.9)  # the one run that has it
    assert out["rows"]["warp"]["temperature_k10_tval"] == [0.0]
    assert out["psnr_k1_warp"] == pytest.approx(15.5)
