"""Inspect proves the reference LiDAR's point-time convention by the geometry it implies.

A motion-compensated sweep (GrandTour's `points_undistorted`, the synthetic driver) is
expressed in the LiDAR frame at the instant its header stamps, and a convention says which
firing that is: `first_point` the sweep's first (offsets from it, >= 0), `header` its last
(offsets <= 0, as velodyne_pointcloud writes `time`), `absolute` whichever end of the decoded
times the header stamp lies nearer. Read the wrong way round, the sweep is placed at the
other end of its firing times: every point moves by the robot's motion over one sweep (up to
a sweep period x speed), what `pipeline.analysis.geometry_faults.time_reversed` injects.

So the proof judges two candidates with the run's geometry check on the proof's views, under
the rig the other decisions settled: the inferred convention (each sweep posed at the decoded
time of the end the convention names) and its reversal (the other end). `prove.settle` keeps
or switches, as for every decision, with one exception: when both agree with the images the
geometry cannot tell them apart and the decision is `unproven: motion too small to tell`,
with the robot's motion over one sweep (mm, deg; the median over the views) and the LiDAR's
azimuth step said (a sparse LiDAR needs more motion), never `proven`. A LiDAR without
per-point time (the HF and KITTI-360 layouts, a driver without a time field) is `unproven`
in one line: every point takes its sweep's stamp.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pipeline.inspect.model import CloudReport, Inspection
from pipeline.inspect.prove_judge import (
    Judged,
    Rig,
    Unjudged,
    judge_rig,
    judged,
    lidar_step,
    rig_poses,
)
from pipeline.inspect.prove_read import ProofData, SweepView

START, END = "start", "end"
REVERSED = {"first_point": "header", "header": "first_point", "absolute": "absolute"}
"""The reference read the other way round (absolute: the header at the other end)."""


@dataclass(frozen=True)
class TimeCandidate:
    """One reading of the convention: its name and the end of the sweep it puts the header
    stamp at (`START` or `END`)."""

    name: str
    end: str


def header_end(reference: str, sweeps: list[SweepView]) -> str:
    """The end of the sweep the header stamps under `reference` (module docstring); for
    `absolute` the end the header stamp lies nearer (median over `sweeps`)."""
    if reference == "first_point":
        return START
    if reference == "header":
        return END
    gaps = [(abs(s.stamp_ns - (s.first_ns or s.stamp_ns)), abs((s.last_ns or s.stamp_ns)
                                                               - s.stamp_ns)) for s in sweeps]
    if not gaps:
        return START
    start, end = np.median(np.array(gaps, np.float64), axis=0)
    return START if start <= end else END


def candidates(cloud: CloudReport, sweeps: list[SweepView]) -> list[TimeCandidate]:
    """The inferred reading first, then its reversal."""
    c = cloud.convention
    ref = str(c.reference)
    end = header_end(ref, sweeps)
    other = END if end == START else START
    return [TimeCandidate(f"{c.unit} {ref} (header at the sweep's {end})", end),
            TimeCandidate(f"{c.unit} {REVERSED[ref]} (header at the sweep's {other})", other)]


def reference_of(name: str) -> str:
    """The reference a candidate's name (`candidates`: `<unit> <reference> (...)`) reads."""
    return name.split(" ")[1] if name.count(" ") >= 1 else ""


def posed_at(sweeps: list[SweepView | None], end: str) -> list[SweepView | None]:
    """The sweeps with their stamp moved to the decoded time of `end`: the instant the
    candidate poses them at."""
    return [None if s is None else dataclasses.replace(
        s, stamp_ns=int((s.first_ns if end == START else s.last_ns) or s.stamp_ns))
        for s in sweeps]  # fmt: skip


def motion_per_sweep(data: ProofData, rig: Rig, sweeps: list[SweepView]) -> tuple[float, float]:
    """(mm, deg): the median over `sweeps` of the body's translation and rotation between its
    first and last point time under `rig`'s pose source (0, 0 without poses there)."""
    try:
        track = rig_poses(data, rig, []).track
    except Unjudged:
        return 0.0, 0.0
    mm, deg = [], []
    for s in sweeps:
        a, b = track.at(float(s.first_ns or s.stamp_ns)), track.at(float(s.last_ns or s.stamp_ns))
        if a is None or b is None:
            continue
        d = np.linalg.solve(a, b)
        mm.append(1e3 * float(np.linalg.norm(d[:3, 3])))
        deg.append(float(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))))
    return (float(np.median(mm)), float(np.median(deg))) if mm else (0.0, 0.0)


@dataclass(frozen=True)
class TimeJudgement:
    """The candidates judged (the inferred first), the motion over one sweep (mm, deg) and the
    LiDAR's azimuth step (deg): what the geometry has to tell the readings apart."""

    inferred: str
    results: tuple[Judged, ...]
    motion_mm: float
    motion_deg: float
    step_deg: float = 0.0

    def motion(self) -> str:
        """`X mm, Y deg per sweep; azimuth step Z deg`."""
        return (f"{self.motion_mm:.0f} mm, {self.motion_deg:.2f} deg per sweep; azimuth step "
                f"{self.step_deg:.2f} deg")  # fmt: skip


def judge_time(data: ProofData, ins: Inspection, rig: Rig,
               cameras: list[str]) -> TimeJudgement | str:  # fmt: skip
    """The reference LiDAR's convention and its reversal judged under `rig` over `cameras`,
    or why it cannot be (one line)."""
    cloud = next((c for c in ins.clouds if c.topic == rig.lidar), None)
    if cloud is None or not cloud.time_field or cloud.convention.reference is None:
        return "no per-point time: every point takes its sweep's stamp; nothing to judge"
    got = data.sweeps.get(rig.lidar, [])
    kept = [s for s in got if s is not None]
    if not kept:
        return "no sweep of it was read"
    cands = candidates(cloud, kept)
    results = []
    for cand in cands:
        moved = dataclasses.replace(data, sweeps={**data.sweeps,
                                                  rig.lidar: posed_at(got, cand.end)})
        try:
            results.append(judged(cand.name, judge_rig(moved, rig, cameras)))
        except Unjudged as err:
            results.append(Judged(cand.name, "inconclusive", None, None, str(err)))
    mm, deg = motion_per_sweep(data, rig, kept)
    step = float(np.degrees(lidar_step(data, rig.lidar)))
    return TimeJudgement(cands[0].name, tuple(results), mm, deg, step)
