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
