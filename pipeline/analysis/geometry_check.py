"""The geometry check after packets: a verdict per camera (`packets.geometry_verdict`) that the
recorded geometry (pose source, frames, extrinsics, clock) puts LiDAR edges on image edges.

One item per recording; the views are built and each camera judged in
`pipeline.analysis.geometry_views` (how, in its docstring). Results: a GEOMETRY row per camera
(`index/<rec>/geometry.parquet`), a `geometry` row per camera in `checks.parquet` (state = the
verdict, the reason as detail) and the manifest's checks; a camera `failed` and not accepted
(`geometry.accept`) fails the item with one line naming it, so the run exits non-zero and the
recording goes no further.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from packets.geometry_verdict import FAILED
from pipeline.analysis.align_lidar import body_track
from pipeline.analysis.geometry_scoring import Poses
from pipeline.analysis.geometry_views import CameraResult, camera_sets, judge_camera
from pipeline.run.keys import ItemKey
from pipeline.run.reads import RECORDING_GROUPS, Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key, index_path
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.layout import OutputLayout
from schemas.missions import mission_of, recording_names
from schemas.recording_index import (
    CHECKS,
    GEOMETRY,
    read_index_table,
    table_path,
    write_index_table,
)
from schemas.stages import GEOMETRY as GEOMETRY_STAGE

CHECK = GEOMETRY_STAGE.name
"""The check's name in checks.parquet: the stage's (`schemas.stages.GEOMETRY`)."""

GEOMETRY_READS = StoreReads(Reads((*RECORDING_GROUPS,), ("images", "valid")))
"""Its recording's group and index; the `images` and `valid` chunks."""


def plan_geometry(cfg: M3GDConfig) -> list[Item]:
    """One item per recording (none when `geometry.enabled` is false); the key covers the
    check's config and everything upstream of packets."""
    if not cfg.geometry.enabled:
        return []
    return [Item(ItemKey(rec), cache_key(CHECK, cfg.geometry, cfg.packets, cfg.encoders,
                                         cfg.ingest, cfg.select, cfg.cache, rec))
            for rec in recording_names(cfg)]


def accepted(cfg: M3GDConfig, rec: str, camera: str) -> bool:
    """Whether the user accepts a `failed` verdict of `camera` of `rec` (`geometry.accept`)."""
    return camera in cfg.geometry.accept or f"{rec}/{camera}" in cfg.geometry.accept


def result_row(cfg: M3GDConfig, rec: str, res: CameraResult) -> dict[str, Any]:
    """The GEOMETRY row of one camera."""
    t, b = res.test, res.best
    return {"camera": res.camera, "verdict": res.verdict.verdict, "reason": res.verdict.reason,
            "cause": res.verdict.cause,
            "accepted": res.verdict.verdict == FAILED and accepted(cfg, rec, res.camera),
            "views": res.evidence.views, "edge_points": res.evidence.points,
            "score": t.observed if t else None, "null_mean": t.null_mean if t else None,
            "null_std": t.null_std if t else None, "z": _finite(t.z) if t else None,
            "p_value": t.p_value if t else None, "wins": t.wins if t else None,
            "best_score": b.score if b else None, "best_moved": b.moved if b else ""}


def _finite(x: float) -> float | None:
    """x, or None when infinite (a null without spread)."""
    return x if np.isfinite(x) else None


def check_row(cfg: M3GDConfig, rec: str, res: CameraResult) -> dict[str, object]:
    """The checks-table row of one camera: topic = its image topic, state = the verdict."""
    v = res.verdict
    detail = v.reason + (f"; likely cause: {v.cause}" if v.cause else "")
    if v.verdict == FAILED and accepted(cfg, rec, res.camera):
        detail += "; accepted (geometry.accept)"
    return {"topic": cfg.ingest.topics.image_topic(res.camera), "check": CHECK,
            "state": v.verdict, "messages": res.evidence.views,
            "flagged": int(v.verdict == FAILED), "rejected": 0, "trusted": 0, "detail": detail}


def write_results(cfg: M3GDConfig, rec: str, results: list[CameraResult]) -> list[dict[str, Any]]:
    """geometry.parquet, and the geometry rows of checks.parquet (replacing earlier ones);
    the checks table's rows after the write."""
    idx = index_path(cfg, rec)
    write_index_table(pa.Table.from_pylist([result_row(cfg, rec, r) for r in results],
                                           schema=GEOMETRY), GEOMETRY, table_path(idx, "geometry"))
    path = table_path(idx, "checks")
    old = read_index_table(path, CHECKS).to_pylist() if path.exists() else []
    rows = [r for r in old if r["check"] != CHECK] + [check_row(cfg, rec, r) for r in results]
    write_index_table(pa.Table.from_pylist(rows, schema=CHECKS), CHECKS, path)
    return rows


def failure_line(rec: str, failed: list[CameraResult]) -> str:
    """One line naming the failed cameras of `rec`, their cause and how to accept them."""
    parts = [f"camera {r.camera}: {r.verdict.reason}; likely cause: {r.verdict.cause}"
             for r in failed]
    names = " ".join(f"--accept-geometry {r.camera}" for r in failed)
    return (f"geometry failed in recording {rec}: {' | '.join(parts)}; its packets would be "
            f"wrong: fix the config (pose source, frames, extrinsics, clock) or accept with "
            f"{names}")


class GeometryFailed(DataError):
    """A camera's geometry verdict is `failed` and the user did not accept it; `checks`: the
    item's `checks.parquet` rows (every camera's verdict), which the run records in the
    manifest as it does for an item that passed (`pipeline.run.runner`)."""

    def __init__(self, line: str, checks: list[dict[str, object]] | None = None) -> None:
        super().__init__(line)
        self.checks = list(checks or [])

    def __reduce__(self) -> tuple[type[GeometryFailed], tuple[str, list[dict[str, object]]]]:
        """Pickled with its rows (a Dask worker sends it back to the scheduler)."""
        return (type(self), (str(self), self.checks))


def run_geometry(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Judge every camera of one recording; write the results; GeometryFailed (one line) when
    a camera failed unaccepted."""
    from pipeline.ingest.sources.staging import staged

    rec = item.key.require_recording()
    body = Poses.of(body_track(index_path(cfg, rec)))
    with staged(mission_of(cfg, rec)) as mission:
        sets = camera_sets(cfg, rec, mission, body)
    results = [judge_camera(cs, body) for cs in sets]
    rows = write_results(cfg, rec, results)
    failed = [r for r in results if r.verdict.verdict == FAILED
              and not accepted(cfg, rec, r.camera)]
    if failed:
        raise GeometryFailed(failure_line(rec, failed), rows)
    return ItemResult(done=len(results), detail={"checks": rows, CHECK: {
        r.camera: r.verdict.verdict for r in results}},
        warnings=[f"geometry {r.camera}: {r.verdict.verdict}: {r.verdict.reason}"
                  for r in results if r.verdict.verdict != "ok"])


def geometry_table(output_dir: Path) -> pa.Table | None:
    """The geometry verdicts of every recording of a local output (`index/<rec>/geometry.parquet`,
    a `recording` column first); None when no recording has one."""
    parts = []
    for f in sorted(OutputLayout(Path(output_dir)).index.glob("*/geometry.parquet")):
        t = read_index_table(f, GEOMETRY)
        parts.append(t.add_column(0, "recording", pa.array([f.parent.name] * t.num_rows,
                                                          pa.string())))  # fmt: skip
    return pa.concat_tables(parts).replace_schema_metadata(None) if parts else None


def verdict_lines(output_dir: Path, recordings: list[str] | None = None) -> list[str]:
    """One line per camera of `recordings` (all when None): recording/camera, the verdict, its
    reason (and cause, acceptance)."""
    table = geometry_table(output_dir)
    rows = [] if table is None else table.to_pylist()
    out = []
    for r in rows:
        if recordings is not None and r["recording"] not in recordings:
            continue
        tail = f"; likely cause: {r['cause']}" if r["cause"] else ""
        tail += " (accepted)" if r["accepted"] else ""
        out.append(f"geometry {r['recording']}/{r['camera']}: {r['verdict']}: {r['reason']}"
                   f"{tail}")
    return out
