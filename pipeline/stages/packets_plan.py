"""`packets.items: auto`: packets items chosen from the worker count and recording sizes.

A packets item is a whole recording (each selected sweep encoded once) or one shard row of
it (shard k of every camera; a sweep selected by views of two rows is encoded by both). With
one task per recording, one long recording keeps one worker busy while the others idle; with
a task per shard row every boundary sweep is encoded twice. `choose_units` splits only where
that shortens the schedule: of the plans splitting the j costliest splittable recordings
(j = 0, 1, ...), the one of the shortest longest-processing-time-first (LPT) makespan over the
workers, and returns the units costliest first, which is the order the executors
hand items out in (one per free worker), so the schedule run is the LPT one planned.

Costs are estimated from the selection and sweep tables (`recording_costs`): the points of
each distinct selected sweep (encoding, the dominant cost) plus VIEW_WEIGHT times the points
of the sweep of each view (projection, support sets, pooling). Outputs do not depend on the
plan (tested): the cache key is the same for every `packets.items`.
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pyarrow.compute as pc

from schemas.cache_layout import GroupAttrs
from schemas.config import M3GDConfig
from schemas.recording_index import (
    SELECTION,
    SELECTION_FILE,
    SELECTION_LIDARS,
    SELECTION_LIDARS_FILE,
    SWEEPS,
    read_index_table,
)

VIEW_WEIGHT = 0.3
"""Cost of one view relative to encoding its sweep once (rough: a view pools the ~third of a
sweep's points in its frustum; encoding computes normals and FPFH over all of them)."""


@dataclass(frozen=True)
class Unit:
    """One packets item: a recording, whole (`row` None) or one of its shard rows."""

    recording: str
    row: int | None
    cost: float

    @property
    def key(self) -> str:
        """Item key: `<rec>` or `<rec>/<row>`."""
        return self.recording if self.row is None else f"{self.recording}/{self.row}"


def makespan(costs: Sequence[float], workers: int) -> float:
    """Finish time of the LPT schedule: costs taken largest first, each to the worker that is
    free first."""
    finish = [0.0] * max(1, workers)
    for cost in sorted(costs, reverse=True):
        heapq.heapreplace(finish, finish[0] + cost)
    return max(finish)


def choose_units(whole: dict[str, float], rows: dict[str, list[float]],
                 workers: int) -> list[Unit]:
    """Units of work for `workers`, costliest first.

    whole: estimated cost of each recording as one item; rows: of each of its shard rows as
    separate items (their sum exceeds the whole cost by the sweeps shared across rows).
    The costliest j splittable recordings are split, j chosen for the shortest planned
    schedule (the fewest splits among equals): a recording is split only when that helps.
    """
    def units(split: set[str]) -> list[Unit]:
        out = [Unit(r, None, c) for r, c in whole.items() if r not in split]
        out += [Unit(r, k, c) for r in split for k, c in enumerate(rows[r])]
        return out

    splittable = sorted((r for r in whole if len(rows.get(r, [])) > 1),
                        key=lambda r: (-whole[r], r))
    best, chosen = makespan(list(whole.values()), workers), 0
    for j in range(1, len(splittable) + 1 if workers > 1 else 1):
        span = makespan([u.cost for u in units(set(splittable[:j]))], workers)
        if span < best * (1 - 1e-9):
            best, chosen = span, j
    plan = units(set(splittable[:chosen]))
    return sorted(plan, key=lambda u: (-u.cost, u.recording, u.row or 0))


def recording_costs(folder: Path, attrs: Sequence[GroupAttrs],
                    merges: bool = False) -> tuple[float, list[float]]:
    """(whole cost, cost per shard row) of one recording's packets, from the selection and
    sweep tables in its index `folder`; rows of `attrs`' shards (the most any camera has).
    `merges`: several LiDARs feed the packets (`selection_lidars`: a view costs each of its
    LiDARs' sweeps)."""
    sel = (read_index_table(folder / SELECTION_LIDARS_FILE, SELECTION_LIDARS) if merges
           else read_index_table(folder / SELECTION_FILE, SELECTION))
    sel = sel.filter(pc.equal(sel["status"], "ok")).select(["camera", "frame", "sweep"])
    sweeps = read_index_table(folder / "sweeps.parquet", SWEEPS).select(["sweep", "n_valid"])
    points = dict(zip(sweeps["sweep"].to_pylist(), sweeps["n_valid"].to_pylist(), strict=True))
    per_view = {a.camera: a.shard_views for a in attrs}
    n_rows = max((-(-a.n_views // a.shard_views) for a in attrs), default=0)
    row_sweeps: list[set[int]] = [set() for _ in range(n_rows)]
    row_views = [0.0] * n_rows
    for cam, frame, sweep in zip(*(sel[c].to_pylist() for c in ("camera", "frame", "sweep")),
                                 strict=True):
        if cam not in per_view:
            continue
        k = frame // per_view[cam]
        if k < n_rows:
            row_sweeps[k].add(sweep)
            row_views[k] += VIEW_WEIGHT * points.get(sweep, 0)
    rows = [sum(points.get(s, 0) for s in ss) + v for ss, v in zip(row_sweeps, row_views,
                                                                   strict=True)]
    every = set().union(*row_sweeps) if row_sweeps else set()
    whole = sum(points.get(s, 0) for s in every) + sum(row_views)
    return float(whole), [float(r) for r in rows]


def planned_workers(cfg: M3GDConfig) -> int:
    """Workers the items will run on: 1 for the local executor, else `dag.workers` (default:
    one per CPU, as `DaskExecutor` starts them)."""
    if cfg.dag.executor == "local":
        return 1
    return cfg.dag.workers or max(1, os.cpu_count() or 1)
