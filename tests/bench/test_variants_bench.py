"""`m3gd bench variants`: sensor variants through synth, ingest, select, packets, accuracy."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from bench.variants import run_variants, summarize
from schemas.errors import DataError

KEYS = {"variants", "false_reject_rate_max", "views_kept_over_clean_min", "depth_absrel_max",
        "silent_losses", "time_convention_errors", "rows"}  # fmt: skip


def _missed_goals(figures: dict[str, Any], absrel_factor: float) -> list[str]:
    """The goals of `m3gd bench variants` that `figures` misses (empty: all met): every key
    present, nothing refused, no false rejects, no silent losses, >= 95 % of the clean views
    kept, depth abs-rel within `absrel_factor` x the default recording's."""
    default = figures.get("depth_absrel_default")
    checks = {
        "keys": set(figures) >= KEYS,
        "refused": figures.get("refused") == [],
        "false_reject_rate_max": figures.get("false_reject_rate_max") == 0.0,
        "silent_losses": figures.get("silent_losses") == 0,
        "time_convention_errors": figures.get("time_convention_errors") == 0,
        "views_kept_over_clean_min": figures.get("views_kept_over_clean_min", 0) >= 0.95,
        "depth_absrel_max": default is not None
        and figures.get("depth_absrel_max", float("inf")) <= absrel_factor * default,
    }
    return [name for name, ok in checks.items() if not ok]


def test_the_cli_runs_a_variant_end_to_end(tmp_path: Path) -> None:
    """`m3gd bench variants --only livox --json`: the default and a Livox-like recording
    through every stage `m3gd run` runs before the model; its rotation check is off."""
    from typer.testing import CliRunner

    from cli.app import app

    out = CliRunner().invoke(app, ["bench", "variants", "--only", "livox", "--seconds", "1.5",
                                   "--workdir", str(tmp_path), "--json"])  # fmt: skip
    assert out.exit_code == 0, out.output
    figures = json.loads(out.stdout)
    assert figures["variants"] == 2
    assert _missed_goals(figures, 1.5) == [], figures
    livox = figures["rows"][1]
    assert livox["variant"] == "livox" and livox["rejected"] == 0
    # livox_ros_driver2: float64 absolute ns, read as such (not as seconds, not as damage)
    assert livox["time_inferred"] == "timestamp ns absolute" == livox["time_written"]
    assert livox["checks_off"] == ["rotation@/boxi/hesai/points_undistorted:off"]


def test_unknown_variants_are_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"unknown sensor variant\(s\) \['vlp32'\]"):
        run_variants(tmp_path, ["vlp32"])


def test_only_takes_groups_and_patterns() -> None:
    from bench.variants import select_variants
    from pipeline.synth.variants import GROUPS

    assert select_variants(["time"]) == list(GROUPS["time"])
    assert select_variants(["time_uint32_*", "livox"]) == [
        "livox", "time_uint32_us_first_point", "time_uint32_ns_first_point"]


def test_summary_of_rows() -> None:
    rows = [{"variant": "default", "false_reject_rate": 0.0, "silent_losses": 0,
             "views_kept": 20, "depth_absrel": 0.05},
            {"variant": "x", "false_reject_rate": 0.02, "silent_losses": 1, "views_kept": 19,
             "depth_absrel": 0.06},
            {"variant": "y", "refused": "ingest m: no"}]  # fmt: skip
    s = summarize(rows)
    assert s["variants"] == 3 and s["refused"] == ["y"] and s["silent_losses"] == 1
    assert s["false_reject_rate_max"] == 0.02 and s["views_kept_over_clean_min"] == 0.95
    assert s["depth_absrel_max"] == 0.06 and s["depth_absrel_default"] == 0.05
    # no decision recorded (and the refused variant) count as convention errors
    assert s["time_convention_errors"] == 3
    rows[0]["time_convention_ok"] = rows[1]["time_convention_ok"] = True
    assert summarize(rows)["time_convention_errors"] == 1


@pytest.mark.slow
def test_every_variant_meets_the_goals(tmp_path: Path) -> None:
    figures = run_variants(tmp_path)
    assert _missed_goals(figures, 1.3) == [], figures
