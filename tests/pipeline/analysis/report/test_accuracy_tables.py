"""The accuracy summary as grouped tables (pipeline.analysis.report.accuracy_tables)."""

from __future__ import annotations

from typing import Any

from pipeline.analysis.report.accuracy_tables import group_title, groupings, overall


def _bin(n: int, abs_rel: float | None) -> dict[str, Any]:
    return {"n": n, "abs_rel": abs_rel, "rmse_m": None if n == 0 else 0.5}


SUMMARY: dict[str, Any] = {
    "recordings": 2, "depth_abs_rel": 0.065,
    "by_abs_dtau_ms": {"0-10": _bin(10, 0.07), "10-20": _bin(0, None), ">=200": _bin(3, 0.2)},
    "views": 362,
    "by_speed_mps": {">=0.8": _bin(5, 0.02)},
    "by_new_thing_unit": {"a": _bin(0, None)},
}


def test_overall_keeps_every_scalar_in_order_and_no_grouping() -> None:
    assert overall(SUMMARY) == [("recordings", 2), ("depth_abs_rel", 0.065), ("views", 362)]


def test_each_grouping_is_a_table_of_its_bins_with_cells_and_names_the_empty_ones() -> None:
    dtau, speed, new = groupings(SUMMARY)
    assert (dtau.key, dtau.title) == ("by_abs_dtau_ms", "by |Δτ| (ms)")
    assert dtau.table.column_names == ["bin", "n", "abs_rel", "rmse_m"]
    assert dtau.table.to_pylist() == [{"bin": "0-10", "n": 10, "abs_rel": 0.07, "rmse_m": 0.5},
                                      {"bin": ">=200", "n": 3, "abs_rel": 0.2, "rmse_m": 0.5}]
    assert dtau.empty_bins == ["10-20"]
    assert speed.title == "by speed (m/s)" and speed.table.num_rows == 1 and not speed.empty_bins
    assert new.table.num_rows == 0 and new.empty_bins == ["a"]  # every bin empty: no row
    assert group_title("by_new_thing_unit") == "by new thing unit"
