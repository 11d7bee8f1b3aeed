"""The geometry check in `m3gd bench variants` (issue 47 items 3 and 4): its verdicts on every
variant, its cost, and the scenes and faults it is proven on.

Every scene's recording is judged clean and textureless. In the first scene every fault of
`pipeline.analysis.geometry_faults` is judged too: the four the generator renders
(`RENDERED`: 2 and 5 degree rotation, 10 cm translation, 50 ms clock offset) each from its own
recording written with the fault while its calibration declares the nominal rig, and read as
it is; the three that are reading mistakes (`INJECTED`: wrong pose frame, cameras swapped,
reversed time convention) injected into what the check reads of the clean recording. Each
case's cameras carry their `evidence` (`rendered` or `injected`); the injected forms of the
four rendered faults are judged too (`<fault>@injected_twin`) and reported beside the count,
so where the two kinds of evidence disagree it shows.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from schemas.config import M3GDConfig

GEOMETRY_SYNTH = {"points_per_sweep": 16384, "cameras": ["front", "left"]}
"""The geometry recordings: the demo's scan density, two cameras (a swap needs two)."""
GEOMETRY_SCENES = ("corridor", "warehouse", "forest", "plaza")
"""Every synthetic scene; the faults are judged in the first."""
TWIN = "injected_twin"
"""The evidence of a rendered fault's injected form, judged beside it on the clean recording:
reported (`geometry_injected_twins`), not counted."""
INGEST = {"cameras": GEOMETRY_SYNTH["cameras"], "out_height": 112, "out_width": 168}
"""The ingest keys of the geometry recordings."""


def accepting(cfg: M3GDConfig) -> M3GDConfig:
    """`cfg` accepting a failed geometry verdict of every camera: the bench reads the verdict
    from `geometry.parquet` instead of losing the row to the refusal."""
    geo = cfg.geometry.model_copy(update={"accept": list(cfg.ingest.cameras)})
    return cfg.model_copy(update={"geometry": geo})


def geometry_row(idx: Path, summaries: Any) -> dict[str, Any]:
    """A variant row's geometry verdict per camera and the geometry and packets stages' wall
    times (s)."""
    import pyarrow.parquet as pq

    secs = {s.name: float(s.seconds) for s in summaries}
    path = idx / "geometry.parquet"
    rows = pq.read_table(path).to_pylist() if path.exists() else []
    return {"geometry": {r["camera"]: r["verdict"] for r in rows},
            "geometry_reasons": {r["camera"]: r["reason"] for r in rows},
            "geometry_seconds": secs.get("geometry"), "packets_seconds": secs.get("packets")}


def _judge(cfg: M3GDConfig, faults: Any) -> dict[str, Any]:
    """`judge_all` over the one recording of `cfg` (ingested and selected): per case, each
    camera's verdict."""
    from pipeline.analysis.align_lidar import body_track
    from pipeline.analysis.geometry_faults import judge_all
    from pipeline.analysis.geometry_views import Poses, camera_sets
    from schemas.missions import mission_of, recording_names

    (rec,) = recording_names(cfg)
    body = Poses.of(body_track(cfg.layout.index_of(rec)))
    sets = {cs.camera: cs for cs in camera_sets(cfg, rec, mission_of(cfg, rec))}
    return judge_all(sets, body, faults=faults)


def _entry(v: Any, faulty: bool, evidence: str) -> dict[str, Any]:
    """One camera's verdict in a case, how it stands (`judged`) and the fault's evidence."""
    from pipeline.analysis.geometry_faults import judged

    return {"verdict": v.verdict, "reason": v.reason, "cause": v.cause,
            "judged": judged(v, faulty), "evidence": evidence}  # fmt: skip


def rendered_case(work: Path, synth: dict[str, Any], scene: str, fault: str) -> dict[str, Any]:
    """Fault `fault` (`geometry_faults.RENDERED`) rendered into a recording of `scene` under
    `work/` (its calibration the nominal rig's), ingested, selected and judged as a clean
    recording is: each camera's entry."""
    from dags.graph import STAGES
    from pipeline.analysis.geometry_faults import RENDERED
    from pipeline.run.service import RunRequest, run_stages
    from pipeline.synth.api import synthesize
    from schemas.config import SynthConfig

    r = RENDERED[fault]
    cfg = SynthConfig.model_validate({**synth, **GEOMETRY_SYNTH, **r.synth, "scenes": [scene]})
    mission = synthesize(work / "recordings", cfg, scene, f"{scene}_{fault}",
                         camera_offset_m=r.camera_offset_m).mission_dir  # fmt: skip
    run = M3GDConfig.model_validate({
        "output_dir": str(work / "out"), "ingest": {**INGEST, "recordings": [str(mission)]},
        "dag": {"retries": 0, "workers": 1}})  # fmt: skip
    run_stages(run, STAGES, RunRequest(only=("ingest", "select")))
    return {c: _entry(v, True, "rendered") for c, v in _judge(run, False)["clean"].items()}


def geometry_cases(work: Path, synth: dict[str, Any],
                   scenes: tuple[str, ...] = GEOMETRY_SCENES) -> dict[str, Any]:
    """Each scene's recording (`GEOMETRY_SYNTH`, default sensors) through synth, ingest and
    select, each camera judged clean and textureless (every image flat); in the first scene
    every fault too (the module docstring): per case, each camera's entry (`_entry`)."""
    from dags.graph import STAGES
    from pipeline.analysis.geometry_faults import RENDERED
    from pipeline.run.service import RunRequest, run_stages

    out: dict[str, Any] = {}
    for k, scene in enumerate(scenes):
        cfg = M3GDConfig.model_validate({
            "output_dir": str(work / f"geometry_{scene}" / "out"),
            "synth": {**synth, **GEOMETRY_SYNTH, "scenes": [scene]}, "ingest": INGEST,
            "dag": {"retries": 0, "workers": 1}})  # fmt: skip
        run_stages(cfg, STAGES, RunRequest(only=("synth", "ingest", "select")))
        for case, verdicts in _judge(cfg, k == 0).items():
            faulty = case not in ("clean", "textureless")
            evidence = "clean" if not faulty else TWIN if case in RENDERED else "injected"
            out[f"{scene}/{case}{'@' + TWIN if evidence == TWIN else ''}"] = {
                c: _entry(v, faulty, evidence) for c, v in verdicts.items()}  # fmt: skip
        if k == 0:
            for fault in RENDERED:
                out[f"{scene}/{fault}"] = rendered_case(work / f"geometry_{scene}_{fault}",
                                                        synth, scene, fault)  # fmt: skip
    return out


def geometry_summary(rows: list[dict[str, Any]],
                     cases: dict[str, Any] | None = None) -> dict[str, Any]:
    """`geometry_false_fail` (failed cameras over every clean variant row and clean or
    textureless scene case), `geometry_faults_detected` (faults whose every camera is failed,
    or inconclusive with a reason), `geometry_fault_evidence` (per fault case, `rendered` or
    `injected`), `geometry_injected_twins` (per rendered fault, whether its injected form was
    detected; not counted) and `geometry_check_cost_over_packets` (the geometry stage's wall
    time over the packets stage's, summed over the variant rows; goal <= 0.1)."""
    false = [f"{r['variant']}/{c}" for r in rows for c, v in r.get("geometry", {}).items()
             if v == "failed"]
    faults: dict[str, bool] = {}
    twins = {case.removesuffix("@" + TWIN): all(v["judged"] == "detected" for v in cams.values())
             for case, cams in (cases or {}).items() if case.endswith("@" + TWIN)}
    for case, cams in (cases or {}).items():
        if case.endswith("@" + TWIN):
            continue
        for c, v in cams.items():
            if v["judged"] == "false_fail":
                false.append(f"{case}/{c}")
        if any(v["judged"] in ("detected", "missed") for v in cams.values()):
            faults[case] = all(v["judged"] == "detected" for v in cams.values())
    geo = sum(r.get("geometry_seconds") or 0.0 for r in rows)
    pk = sum(r.get("packets_seconds") or 0.0 for r in rows)
    return {"geometry_false_fail": len(false), "geometry_false_fail_cases": false,
            "geometry_faults_detected": {
                "count": sum(faults.values()), "of": len(faults),
                "detected": sorted(f for f, ok in faults.items() if ok),
                "missed": sorted(f for f, ok in faults.items() if not ok)},
            "geometry_injected_twins": twins,
            "geometry_fault_evidence": {
                f: next(iter(cases[f].values())).get("evidence") for f in sorted(faults)}
            if cases else {},
            "geometry_check_cost_over_packets": round(geo / pk, 4) if pk else None,
            "geometry_cases": cases or {}}
