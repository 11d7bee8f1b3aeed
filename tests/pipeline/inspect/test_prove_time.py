"""Inspect proves the point-time convention by its geometry (`pipeline.inspect.prove_time`):
which end of the sweep each reading puts the header at; the inferred convention proven on the
synthetic drivers' conventions; one declared the other way round switched, never proven; both
readings agreeing (motion too small for the geometry to tell them apart) left unproven, with
the motion said."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from packets.edges import scan_edges
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.inspect.config_out import build_config
from pipeline.inspect.model import CloudReport, Convention, Inspection, TfReport
from pipeline.inspect.prove import (
    PROVEN,
    SWITCHED,
    UNPROVEN,
    Proof,
    declarable,
    prove,
    settle_time,
)
from pipeline.inspect.prove_judge import Judged, Rig
from pipeline.inspect.prove_read import ProofData, SweepView
from pipeline.inspect.prove_time import (
    END,
    START,
    TimeJudgement,
    candidates,
    header_end,
    judge_time,
    posed_at,
)
from pipeline.inspect.recording import inspect_recording
from tests.pipeline.inspect.prove_sources_kit import synth_dense

FLIP = {"header": "first_point", "first_point": "header"}


def _sweep(stamp: int, first: int, last: int) -> SweepView:
    xyz = np.zeros((0, 3), np.float32)
    return SweepView("/l", stamp, stamp, scan_edges(xyz, np.zeros(0, np.float32)), first, last)


def test_each_reference_names_the_end_the_header_stamps() -> None:
    start = [_sweep(100, 100, 200), _sweep(300, 301, 400)]
    end = [_sweep(200, 100, 200), _sweep(400, 300, 399)]
    assert header_end("first_point", end) == START  # the claim, whatever the times say
    assert header_end("header", start) == END
    assert (header_end("absolute", start), header_end("absolute", end)) == (START, END)


def test_candidates_are_the_inferred_reading_and_its_reversal() -> None:
    cloud = dataclasses.replace(_cloud(), convention=Convention("auto", "s", "header"))
    got = candidates(cloud, [_sweep(200, 100, 200)])
    assert [(c.name, c.end) for c in got] == [("s header (header at the sweep's end)", END),
                                             ("s first_point (header at the sweep's start)",
                                              START)]  # fmt: skip
    moved = posed_at([_sweep(200, 100, 200), None], START)
    assert moved[0] is not None and moved[0].stamp_ns == 100 and moved[1] is None
    end = posed_at([_sweep(200, 100, 190)], END)[0]
    assert end is not None and end.stamp_ns == 190


def _cloud() -> CloudReport:
    return CloudReport("/l", "lidar", (), 0, 0, 0, 0, False, False, "time", "float32", (),
                       0.1, (), Convention("", None, None))  # fmt: skip


def _time_proof(ins: Inspection) -> Proof:
    report, _ = prove(ins)
    proof = report.of(f"point_time {ins.clouds[0].topic}")
    assert proof is not None
    return proof


def _declared(ins: Inspection, reference: str) -> Inspection:
    """`ins` with its LiDAR's convention declared with another reference."""
    c = ins.clouds[0]
    bad = dataclasses.replace(c, convention=dataclasses.replace(c.convention, reference=reference))
    return dataclasses.replace(ins, clouds=(bad, *ins.clouds[1:]))


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["time_float32_s_header", "time_float64_ms_first_point"])
def test_the_inferred_convention_is_proven_and_its_reversal_switched(
        tmp_path_factory: pytest.TempPathFactory, variant: str) -> None:  # fmt: skip
    ins = inspect_recording(synth_dense(tmp_path_factory, variant, variant=variant))
    ref = str(ins.clouds[0].convention.reference)
    right = _time_proof(ins)
    assert right.status == PROVEN and ref in right.kept, right.line()
    reversal = right.candidates[1]
    assert "mm" in right.note and (reversal.verdict != "ok" or (
        (right.candidates[0].z or 0) - (reversal.z or 0) >= 3))  # fmt: skip
    declared = _declared(ins, FLIP[ref])  # declared the other way round
    report, fixed = prove(declared)
    wrong = report.of(f"point_time {ins.clouds[0].topic}")
    assert wrong is not None and wrong.status == SWITCHED and wrong.kept == right.kept
    assert wrong.evidence.split(" ")[1] == FLIP[ref]
    assert fixed.clouds[0].convention.reference == ref  # what the configuration declares
    cfg, _ = build_config(fixed, Path(ins.path))
    written = cfg.ingest.topics.lidar_point_time
    assert not isinstance(written, str) and written.reference == ref


def test_both_readings_agreeing_is_unproven_with_the_motion_said() -> None:
    ok, bad = _j("s header (end)", "ok", 9), _j("s first_point (start)", "inconclusive", 6)
    same = settle_time("point_time /l", TimeJudgement(ok.name, (ok, _j("b", "ok", 8)), 3.4,
                                                      0.012, 2.81))  # fmt: skip
    assert same.status == UNPROVEN and same.kept == ok.name
    assert same.summary().startswith("unproven: motion too small to tell (3 mm, 0.01 deg per "
                                     "sweep; azimuth step 2.81 deg); s header (end) kept on "
                                     "the evidence")  # fmt: skip
    told = settle_time("point_time /l", TimeJudgement(ok.name, (ok, bad), 82.0, 1.85, 1.4))
    assert told.status == PROVEN and "(the robot moves 82 mm, 1.85 deg per sweep" in told.summary()
    apart = settle_time("point_time /l", TimeJudgement(ok.name, (ok, _j("b", "ok", 5.5)), 82.0,
                                                       1.85, 1.4))  # fmt: skip
    assert (apart.status, apart.kept) == (PROVEN, ok.name)  # z 9 against 5.5: told apart
    assert "both agree with the images, s header (end) by z 3.5" in apart.summary()
    better = settle_time("point_time /l", TimeJudgement("b", (_j("b", "ok", 5.5), ok), 82.0,
                                                        1.85, 1.4))  # fmt: skip
    assert (better.status, better.evidence, better.kept) == (SWITCHED, "b", ok.name)
    flipped = settle_time("point_time /l", TimeJudgement(bad.name, (bad, ok), 82.0, 1.85))
    assert (flipped.status, flipped.kept) == (SWITCHED, ok.name)
    none = settle_time("point_time /l", "no per-point time: every point takes its sweep's stamp")
    assert none.summary() == "unproven: no per-point time: every point takes its sweep's stamp"


def _j(name: str, verdict: str, z: float) -> Judged:
    return Judged(name, verdict, z / 20, z, "" if verdict == "ok" else "x")


def test_no_time_field_is_said_in_one_line(tmp_path: Path) -> None:
    ins = Inspection(str(tmp_path), "rosbag1", {}, (), TfReport(), (_cloud(),), ())
    got = judge_time(ProofData(tmp_path, TfTree()), ins, Rig({}, "/l", "lidar", {}), [])
    assert isinstance(got, str) and "no per-point time" in got


def test_a_switch_the_configuration_cannot_declare_is_unproven() -> None:
    """Absolute point times measure which end the header lies nearer: the images favouring
    the other end cannot be declared, so the evidence's reading is kept, unproven, saying so;
    a switch between two references stays a switch."""
    start, end = _j("ns absolute (header at the sweep's start)", "failed", 1), _j(
        "ns absolute (header at the sweep's end)", "ok", 9)
    switched = settle_time("point_time /l", TimeJudgement(start.name, (start, end), 82.0, 1.85))
    assert switched.status == SWITCHED  # what settle alone says
    kept = declarable(switched)
    assert (kept.status, kept.kept) == (UNPROVEN, start.name)
    assert kept.summary().startswith(f"unproven: the images favour {end.name}, which absolute "
                                     "point times cannot declare;")
    first = _j("s first_point (header at the sweep's start)", "failed", 1)
    header = _j("s header (header at the sweep's end)", "ok", 9)
    real = settle_time("point_time /l", TimeJudgement(first.name, (first, header), 82.0, 1.85))
    assert declarable(real) is real and real.status == SWITCHED
