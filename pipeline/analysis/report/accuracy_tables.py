"""The accuracy summary (`stats/accuracy_summary.json`) as small tables a reader scans: the
overall figures, then one table per grouping (`by_…`: |Δτ|, speed, yaw rate), its bins as
rows and the metrics as columns. Pure functions of the summary dict (no file access); the
report and `m3gd accuracy` print the same tables."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pyarrow as pa

GROUP_PREFIX = "by_"
GROUP_TITLES = {
    "by_abs_dtau_ms": "by |Δτ| (ms)",
    "by_speed_mps": "by speed (m/s)",
    "by_abs_yaw_rate_rps": "by |yaw rate| (rad/s)",
}
"""Titles of the groupings the accuracy stage writes; another `by_x_unit` reads `by x unit`."""


@dataclass(frozen=True)
class Grouping:
    """One grouping: its key, title, the table of its bins with cells, and the bins without."""

    key: str
    title: str
    table: pa.Table
    empty_bins: list[str]


def overall(summary: dict[str, Any]) -> list[tuple[str, object]]:
    """(name, value) of every figure that is not a grouping, in the summary's order."""
    return [(k, v) for k, v in summary.items() if not isinstance(v, dict)]


def group_title(key: str) -> str:
    """`by_abs_dtau_ms` -> `by |Δτ| (ms)`; an unknown key with its underscores as spaces."""
    return GROUP_TITLES.get(key, key.replace("_", " "))


def groupings(summary: dict[str, Any]) -> list[Grouping]:
    """Every `by_…` entry (bin -> {metric: value}) as a table: a `bin` column, then the
    metrics in the order of the first bin; bins with no cell (n = 0) are left out and named."""
    out = []
    for key, bins in summary.items():
        if not (key.startswith(GROUP_PREFIX) and isinstance(bins, dict)):
            continue
        full = {b: m for b, m in bins.items() if isinstance(m, dict) and m.get("n")}
        empty = [b for b in bins if b not in full]
        metrics = list(next(iter(full.values()), {}))
        columns: dict[str, list[Any]] = {"bin": list(full)}
        for metric in metrics:
            columns[metric] = [m.get(metric) for m in full.values()]
        out.append(Grouping(key, group_title(key), pa.table(columns), empty))
    return out
