"""`m3gd bench variants`: every sensor variant through the pipeline against the default synth.

For each variant (`pipeline.synth.variants.VARIANTS`) one small recording of the same scene,
seed and motion is synthesized, run through synth, ingest, select and packets in-process (the
stages `m3gd run` runs first), and measured against its ground truth:

- false rejects: messages the run rejected (every reject reason that drops a message read) over
  the messages read; the synthetic recordings hold no damaged message, so every one is false;
- views kept: accepted views over those of the default recording;
- depth abs-rel of the packets against the ground-truth cell depths (`m3gd accuracy`);
- silent losses: messages read but neither kept nor rejected (the accounting);
- which plausibility checks were switched off or capped on which topic (`checks.parquet`);
- time convention errors: variants whose point-time convention, as ingest decided it (the
  sweeps table's time_* columns), is not the one the generator wrote (a refused variant counts);
- the geometry verdict (every run ends with the `geometry` stage, every camera accepted so a
  failed verdict is read, not refused; `bench.variants_geometry.geometry_row`): failed cameras of
  clean variants and scenes (`geometry_false_fail`, goal 0), the injected faults seen
  (`geometry_faults_detected`: failed, or inconclusive with the reason, never ok) and the
  check's cost over the packets stage's (`geometry_check_cost_over_packets`, goal <= 0.1);
- inspect-written configurations: for every variant, the configuration `m3gd inspect
  --write-config` writes for its recording runs through ingest and select
  (`bench.variants_rig.inspect_config`, the bench's output folder, size and checks added);
  `inspect_config_runs` counts those that kept >= 0.95 of the clean run's views per camera
  (`passed`) over those run (`run`), `inspect_config_kept_min` the lowest ratio.

Rig variants (group `rig`, `pipeline.synth.variants_rig`: renamed and ten cameras, raw Bayer
and PNG images, a CameraInfo change, split bags, a rosbag2 folder, pose odometry) change a
written default-sensor mission; no default config names their cameras, so each runs (ingest,
select, packets, accuracy) under its inspect-written configuration, and that run is its
inspect run too. Views are compared per camera configured (ten cameras keep ten views a time).

The checks judge every message (`ingest.checks.trust_checksums` off): the synthetic bags' LZ4
chunks carry checksums, which would otherwise let ingest skip them.

A variant that ingest refuses (a one-line data error before any work) is listed with its
refusal. Goals (the issue's): false_reject_rate_max <= 0.01, views_kept_over_clean_min >= 0.95,
silent_losses 0, time_convention_errors 0, depth_absrel_max within the default's figures.
`--only` takes variant names, group names (`pipeline.synth.variants.GROUPS`: `sensors`, `time`;
`rig` and `tf`) or shell patterns (`time_float64_*`); `geometry` runs the geometry check's
scene and fault cases, `point_time` inspect's point-time proof on every time-convention variant
(`bench.variants_time_proof`; the full matrix runs both).
"""

from __future__ import annotations

import fnmatch
import shutil
import time
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from bench.variants_geometry import (
    GEOMETRY_SCENES,
    accepting,
    geometry_cases,
    geometry_row,
    geometry_summary,
)
from bench.variants_rig import (
    bench_keys,
    decision_truth,
    inspect_config,
    merged_lidars,
    rig_cameras,
    rig_mission,
    wrong_decisions,
)
from bench.variants_sources import (
    CELLS_TABLE,
    SOURCE_VARIANTS,
    packets_vs_default,
    source_mission,
    source_truth,
    written_time,
)
from bench.variants_time_proof import run_time_proof
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.recording_index import MESSAGE_REASONS

STAGES_RUN = ["synth", "ingest", "select", "packets", "geometry"]
SYNTH = {"seconds": 3.0, "image_width": 192, "image_height": 128, "points_per_sweep": 4096,
         "cameras": ["front"], "scenes": ["corridor"]}  # fmt: skip
"""A small recording: 3 s, one camera, 4096 points a sweep."""
INGEST = {"out_height": 112, "out_width": 168, "checks": {"trust_checksums": False}}
"""The ingest keys of every bench run: a small output size; the checks judge every message
(the synthetic chunks are checksummed, which would let them skip every one): what a recording
without chunk checksums gets."""
KEPT_GOAL = 0.95
"""Views an inspect-written configuration keeps over the clean run's, at least."""


def variant_config(work: Path, name: str, synth: dict[str, Any] | None = None) -> M3GDConfig:
    """The config of one sensor variant's run under `work/<name>/`."""
    return M3GDConfig.model_validate({
        "output_dir": str(work / name / "out"),
        "synth": {**SYNTH, **(synth or {}), "variant": name},
        "ingest": {"cameras": ["front"], **INGEST},
        "cache": {"shard_views": 8},
        "dag": {"retries": 0, "workers": 1},
    })  # fmt: skip


def _message_counts(idx: Path) -> tuple[int, int, int]:
    """(messages read, rejected, unaccounted) of one recording's index."""
    acc = pq.read_table(idx / "accounting.parquet").to_pylist()
    read = sum(int(r["read"]) for r in acc)
    unaccounted = sum(abs(int(r["read"]) - int(r["kept"]) - int(r["rejected"])) for r in acc)
    reasons = {m.value for m in MESSAGE_REASONS}
    rejects = pq.read_table(idx / "rejects.parquet", columns=["reason"]).column(0).to_pylist()
    return read, sum(r in reasons for r in rejects), unaccounted


def _views(cfg: M3GDConfig) -> tuple[str, list[str]]:
    """(the run's one recording, its selection statuses)."""
    from schemas.missions import recording_names

    (rec,) = recording_names(cfg)
    idx = cfg.layout.index_of(rec)
    return rec, pq.read_table(idx / "selection.parquet", columns=["status"]).column(0).to_pylist()


def _failed(summaries: Any) -> str:
    """The failures of a run's stage summaries in one line ('' when none)."""
    failed = {k: v for s in summaries for k, v in s.failed.items()}
    return "; ".join(f"{k}: {v}" for k, v in sorted(failed.items()))


def run_variant(work: Path, name: str, synth: dict[str, Any] | None = None) -> dict[str, Any]:
    """One variant through synth, ingest, select, packets and accuracy, and its inspect-written
    configuration through ingest and select: its row. A rig variant's mission is written and
    changed first (`bench.variants_rig`); it runs under its inspect-written configuration."""
    from dags.graph import STAGES
    from pipeline.analysis.accuracy import run_accuracy
    from pipeline.run.service import RunRequest, run_stages
    from schemas.missions import mission_of

    t0 = time.perf_counter()
    shutil.rmtree(work / name, ignore_errors=True)
    row: dict[str, Any] = {"variant": name}
    stages = STAGES_RUN
    rig = is_rig(name)
    if rig:
        size = {**SYNTH, **(synth or {})}
        mission, truth = written_mission(work / name / "recordings", name, size)
        try:
            raw, warnings, ins = inspect_config(mission, work / name / "inspect.yaml")
            row.update(_decided(ins, truth))
            if name == "two_lidars":
                raw = merged_lidars(raw)
            cfg = bench_keys(raw, work / name / "out", INGEST)
        except DataError as err:
            row.update(refused=f"inspect --write-config: {err}", inspect_error=str(err))
            return row
        row["inspect_warnings"] = warnings
        stages = STAGES_RUN[1:]
    else:
        cfg = variant_config(work, name, synth)
    cfg = accepting(cfg)
    summaries = run_stages(cfg, STAGES, RunRequest(only=tuple(stages))).summaries
    failed = _failed(summaries)
    if failed:
        row["refused"] = failed
        if rig:
            row["inspect_error"] = failed
        return row
    rec, status = _views(cfg)
    idx = cfg.layout.index_of(rec)
    read, rejected, unaccounted = _message_counts(idx)
    checks = pq.read_table(idx / "checks.parquet").to_pylist()
    report = run_accuracy(cfg, plots=False)
    acc = report.summary
    row[CELLS_TABLE] = str(report.tables[0]) if report.tables else None
    row.update(_time_convention(idx, name))
    row.update(geometry_row(idx, summaries))
    row.update(messages=read, rejected=rejected, false_reject_rate=rejected / max(read, 1),
               silent_losses=unaccounted, cameras=len(cfg.ingest.cameras), views=len(status),
               views_kept=sum(s == "ok" for s in status),
               depth_absrel=acc.get("depth_abs_rel"), cells=acc.get("cells"),
               checks_off=sorted(f"{c['check']}@{c['topic']}:{c['state']}" for c in checks
                                 if c["state"] != "on" and c["check"] != "geometry"))  # fmt: skip
    if rig:  # the run above is the inspect-written configuration's
        row.update(inspect_cameras=row["cameras"], inspect_views_kept=row["views_kept"],
                   inspect_time_read=row["time_inferred"],
                   inspect_time_ok=row["time_convention_ok"])  # fmt: skip
    else:
        row.update(inspect_run(work / name, mission_of(cfg, rec), name))
    row["seconds"] = round(time.perf_counter() - t0, 1)
    return row


def inspect_run(work: Path, mission: Path, name: str) -> dict[str, Any]:
    """The configuration `inspect --write-config` writes for `mission` (of variant `name`), run
    through ingest and select under `work/` (`bench_keys` added): its cameras, views kept and
    the point-time convention its ingest read (`inspect_time_ok`: the one written), or its
    error."""
    from dags.graph import STAGES
    from pipeline.run.service import RunError, RunRequest, run_stages
    from pipeline.synth.variants import VARIANTS

    v = VARIANTS[name]
    decided: dict[str, Any] = {}
    try:
        raw, warnings, ins = inspect_config(mission, work / "inspect.yaml")
        cameras = [str(c) for c in SYNTH["cameras"]]  # type: ignore[attr-defined]
        decided = _decided(ins, decision_truth(name, cameras, v.lidar_frame, v.camera_frame))
        cfg = bench_keys(raw, work / "inspect_out", INGEST)
        failed = _failed(run_stages(cfg, STAGES, RunRequest(only=("ingest", "select"))).summaries)
    except (DataError, RunError) as err:
        return {**decided, "inspect_error": str(err)}
    if failed:
        return {**decided, "inspect_error": failed}
    rec, status = _views(cfg)
    conv = _time_convention(cfg.layout.index_of(rec), name)
    return {**decided, "inspect_cameras": len(cfg.ingest.cameras),
            "inspect_views_kept": sum(s == "ok" for s in status), "inspect_warnings": warnings,
            "inspect_time_read": conv["time_inferred"],
            "inspect_time_ok": conv["time_convention_ok"]}


def _decided(ins: Any, truth: Any) -> dict[str, Any]:
    """A row's inspect decisions (one line each), where they differ from `truth`
    (`inspect_wrong`: empty when none) and the inspection's time (s)."""
    return {"inspect_decisions": [d.line() for d in ins.decisions],
            "inspect_wrong": wrong_decisions(ins.decisions, truth),
            "inspect_seconds": round(float(ins.seconds), 3)}


def is_rig(name: str) -> bool:
    """Whether variant `name` is a rig, TF or source variant (a written mission changed or
    exported afterwards, run under its inspect-written configuration)."""
    from pipeline.synth.variants_rig import RIG_VARIANTS
    from pipeline.synth.variants_tf import TF_VARIANTS

    return name in RIG_VARIANTS or name in TF_VARIANTS or name in SOURCE_VARIANTS


def written_mission(root: Path, name: str, size: dict[str, Any]) -> tuple[Path, Any]:
    """The mission of rig, TF or source variant `name` written under `root/<name>/`
    (`rig_mission`, `source_mission`) and the decisions inspect must make on it."""
    if name in SOURCE_VARIANTS:
        return source_mission(root, name, size), source_truth(name, size["cameras"])
    return rig_mission(root, name, size), decision_truth(name, rig_cameras(name,
                                                                           size["cameras"]))


def _time_convention(idx: Path, name: str) -> dict[str, Any]:
    """The convention ingest decided (sweeps table) against the one the generator wrote (a
    source variant's: `bench.variants_sources.written_time`)."""
    from pipeline.synth.variants import VARIANTS

    conv = VARIANTS.get(name, VARIANTS["default"]).lidar.time_convention  # rig: default sensors
    cols = ["time_field", "time_unit", "time_reference"]
    sweeps = pq.read_table(idx / "sweeps.parquet", columns=cols).to_pylist()
    decided = {" ".join(r[c] for c in cols) for r in sweeps}
    written = " ".join(written_time(name, (conv.field, conv.unit, conv.reference)))
    return {"time_written": written, "time_inferred": "; ".join(sorted(decided)),
            "time_convention_ok": decided == {written}}


def _per_camera(r: dict[str, Any], prefix: str = "") -> float:
    """A row's views kept per camera configured (`prefix`: `inspect_` for its inspect run)."""
    return float(r[f"{prefix}views_kept"]) / max(int(r.get(f"{prefix}cameras", 1)), 1)


def summarize(rows: list[dict[str, Any]], cases: dict[str, Any] | None = None) -> dict[str, Any]:
    """The figures over variant rows (the first row is the default, the clean reference) and
    the geometry check's scene and fault cases (`geometry_cases`). Views kept are compared
    per camera (a ten-camera rig keeps ten views a time)."""
    same = packets_vs_default(rows)
    ran = [r for r in rows if "refused" not in r]
    clean = next((r for r in ran if r["variant"] == "default"), None)
    ref = _per_camera(clean) if clean else None
    for r in ran:
        r["views_kept_over_clean"] = _per_camera(r) / ref if ref else None
    tried = [r for r in rows if "inspect_views_kept" in r or "inspect_error" in r]
    for r in tried:
        kept = _per_camera(r, "inspect_") / ref if ref and "inspect_views_kept" in r else None
        r["inspect_kept_over_clean"] = kept
        r["inspect_config_ok"] = kept is not None and kept >= KEPT_GOAL
    absrel = [r["depth_absrel"] for r in ran if r["depth_absrel"] is not None]
    over = [r["views_kept_over_clean"] for r in ran if r["views_kept_over_clean"] is not None]
    insp = [r["inspect_kept_over_clean"] for r in tried]
    return {
        "variants": len(rows),
        "refused": sorted(r["variant"] for r in rows if "refused" in r),
        "false_reject_rate_max": max((r["false_reject_rate"] for r in ran), default=None),
        "views_kept_over_clean_min": min(over, default=None),
        "depth_absrel_max": max(absrel, default=None),
        "depth_absrel_default": clean["depth_absrel"] if clean else None,
        "silent_losses": sum(r["silent_losses"] for r in ran),
        "time_convention_errors": sum(not r.get("time_convention_ok", False) for r in rows),
        # every variant's inspect-written configuration: passed (>= KEPT_GOAL of the clean
        # run's views per camera) over run; a run that failed counts as run, not passed
        "inspect_config_runs": {"passed": sum(r["inspect_config_ok"] for r in tried),
                                "run": len(tried)},
        "inspect_config_kept_min": None if None in insp else min(insp, default=None),
        # variants whose inspect decisions (pose source, LiDARs, camera frames) differ from
        # the written truth; a variant never inspected counts
        "inspect_wrong_decisions": sum(r.get("inspect_wrong", ["not inspected"]) != []
                                       for r in rows),
        "inspect_seconds_max": max((r["inspect_seconds"] for r in rows
                                    if "inspect_seconds" in r), default=None),
        # source variants holding the bags' bytes (MCAP): the largest packet depth difference
        # (m) from the default's over the same cells (`bench.variants_sources`)
        "source_packets_max_diff_m": same,
        **geometry_summary(ran, cases),
        "rows": rows,
    }


def run_variants(work: Path, names: list[str] | None = None,
                 synth: dict[str, Any] | None = None,
                 scenes: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Run the default and every variant in `names` (all by default; `select_variants`), and
    the geometry check on `scenes` (faults in the first; `bench.variants_geometry.geometry_cases`;
    default: every scene with every variant or when `names` holds `geometry`, none otherwise),
    and the point-time proof (`bench.variants_time_proof`: with every variant or when `names`
    holds `point_time`); the figures."""
    wanted = [n for n in names or [] if n not in ("geometry", "point_time")]
    if scenes is None:
        scenes = GEOMETRY_SCENES if not names or "geometry" in names else ()
    names_ = ["default", *[n for n in (select_variants(wanted) if wanted or not names else [])
                           if n != "default"]]
    t0 = time.perf_counter()
    rows = [run_variant(work, n, synth) for n in names_]
    size = {k: v for k, v in {**SYNTH, **(synth or {})}.items() if k != "scenes"}
    out = summarize(rows, geometry_cases(work, size, scenes) if scenes else None)
    if not names or "point_time" in names:
        out |= run_time_proof(work / "point_time", size)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def variant_groups() -> dict[str, list[str]]:
    """The bench's groups: the sensor variant groups (`pipeline.synth.variants.GROUPS`), `rig`
    (`pipeline.synth.variants_rig.RIG_VARIANTS`) and `tf`
    (`pipeline.synth.variants_tf.TF_VARIANTS`)."""
    from pipeline.synth.variants import GROUPS
    from pipeline.synth.variants_rig import RIG_VARIANTS
    from pipeline.synth.variants_tf import TF_VARIANTS

    return {**{g: list(vs) for g, vs in GROUPS.items()}, "rig": list(RIG_VARIANTS),
            "tf": list(TF_VARIANTS), "sources": list(SOURCE_VARIANTS)}  # fmt: skip


def select_variants(names: list[str] | None) -> list[str]:
    """Variant names from names, group names and shell patterns (None: every variant), in
    registry order; DataError for one that matches nothing."""
    groups = variant_groups()
    every = [n for vs in groups.values() for n in vs]
    if not names:
        return every
    chosen: set[str] = set()
    for n in names:
        found = set(groups[n]) if n in groups else set(fnmatch.filter(every, n))
        if not found:
            raise DataError(f"unknown sensor variant(s) ['{n}']; known groups: "
                            f"{', '.join(groups)}; names: {', '.join(every)}")
        chosen |= found
    return [v for v in every if v in chosen]


def decisions_only(work: Path, names: list[str] | None = None,
                   synth: dict[str, Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """Every variant's recording written and inspected, no stage run: per variant, where
    inspect's decisions differ from its truth and the inspection's time (s); the count of
    variants decided wrongly (`inspect_wrong_decisions`). The decisions of `run_variants`
    without its runs (minutes instead of the better part of an hour)."""
    from pipeline.inspect.recording import inspect_recording
    from pipeline.synth.api import synthesize
    from pipeline.synth.variants import VARIANTS
    from schemas.config import SynthConfig

    size = {**SYNTH, **(synth or {})}
    cams = [str(c) for c in size["cameras"]]  # type: ignore[attr-defined]
    rows: list[dict[str, Any]] = []
    for name in ["default", *[n for n in select_variants(names) if n != "default"]]:
        shutil.rmtree(work / name, ignore_errors=True)
        if is_rig(name):
            mission, truth = written_mission(work, name, size)
        else:
            cfg = SynthConfig.model_validate({**{k: v for k, v in size.items() if k != "scenes"},
                                              "variant": name})  # fmt: skip
            synthesize(work, cfg, "corridor", name)
            mission, v = work / name, VARIANTS[name]
            truth = decision_truth(name, cams, v.lidar_frame, v.camera_frame)
        ins = inspect_recording(mission)
        rows.append({"variant": name, "inspect_wrong": wrong_decisions(ins.decisions, truth),
                     "inspect_seconds": round(float(ins.seconds), 3)})  # fmt: skip
    return {"variants": len(rows),
            "inspect_wrong_decisions": sum(bool(r["inspect_wrong"]) for r in rows),
            "inspect_seconds_max": max(r["inspect_seconds"] for r in rows), "rows": rows}
