"""`m3gd accuracy`'s summary tables and `stats summary --json`'s JSON Lines (cli.analysis,
cli.stats), on summaries built here."""

from __future__ import annotations

import datetime as dt
import json

import pyarrow as pa
import pytest

from cli.analysis import print_accuracy
from cli.stats import json_lines


def test_accuracy_prints_overall_then_one_table_per_grouping(
        capsys: pytest.CaptureFixture[str]) -> None:
    print_accuracy({"cells": 7, "depth_abs_rel": 0.0651031,
                    "by_abs_dtau_ms": {"0-10": {"n": 7, "abs_rel": 0.05},
                                       ">=200": {"n": 0, "abs_rel": None}}})
    out = capsys.readouterr().out
    assert out.index("depth_abs_rel") < out.index("by |Δτ| (ms)") < out.index("0-10")
    assert "0.0651 " in out and "0.0651031" not in out  # 4 significant digits
    assert "(no cell in bin >=200)" in out and "{" not in out  # no raw JSON


def test_accuracy_prints_settings_apart_from_results(
        capsys: pytest.CaptureFixture[str]) -> None:
    print_accuracy({"recordings": 2, "select_time_offset_s": 0.012, "front_surface": True,
                    "cells": 12345, "depth_abs_rel": 0.5})
    out = capsys.readouterr().out
    results, settings = out.split("settings (the configuration these results used)")
    assert "cells" in results and "depth_abs_rel" in results
    assert "select_time_offset_s" not in results and "front_surface" not in results
    assert "select_time_offset_s" in settings and "True" in settings
    rows = [line for line in results.splitlines() if "recordings" in line or "cells" in line]
    assert rows[0].index("2 ") == rows[1].index("12345") + 4  # values right-aligned


def test_summary_json_is_one_object_per_row_with_its_report_name() -> None:
    results = {"dtau": pa.table({"recording": ["a", "b"], "views": [3, 4]}),
               "checks": pa.table({"day": [dt.date(2026, 11, 26)]}),
               "rejects": pa.table({"reason": pa.array([], pa.string())})}
    lines = json_lines(results)
    assert [json.loads(line) for line in lines] == [
        {"summary": "dtau", "recording": "a", "views": 3},
        {"summary": "dtau", "recording": "b", "views": 4},
        {"summary": "checks", "day": "2026-11-26"}]
    assert all("\n" not in line for line in lines)


def test_summary_json_refuses_a_column_named_like_its_report_field() -> None:
    import typer

    assert json_lines({"r": pa.table({"x": [1]})}) == ['{"summary": "r", "x": 1}']
    with pytest.raises(typer.Exit):
        json_lines({"r": pa.table({"summary": [1]})})
