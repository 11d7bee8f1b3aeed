"""Inspect proves its decisions by their geometry (`pipeline.inspect.prove`): the wheel edge of
`tf_wheels` fails and the odom edge passes; an evidence pick that is wrong (the wheel, what
inspect took before issue 47; an image frame_id naming another camera's frame) is switched;
every candidate failing is said; textureless views leave the evidence's pick unproven."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import cast

import numpy as np
import pytest

from pipeline.inspect.config_out import build_config, decision_lines
from pipeline.inspect.model import Inspection
from pipeline.inspect.prove import (
    DISAGREES,
    PROVEN,
    SWITCHED,
    UNPROVEN,
    Proof,
    ProofReport,
    prove,
    settle,
)
from pipeline.inspect.prove_judge import Judged
from pipeline.inspect.prove_source import read_proof_data
from pipeline.inspect.recording import inspect_recording
from tests.pipeline.inspect.provekit import FRONT, FRONT_INFO, restamped, variant

ODOM = "/tf odom->base"
WHEELS = ("/tf base->wheel_left_link", "/tf base->wheel_right_link")


def _j(name: str, verdict: str, z: float | None = None) -> Judged:
    return Judged(name, verdict, None if z is None else z / 10, z, "" if verdict == "ok" else "x")


def test_settle_keeps_switches_and_says_when_nothing_agrees() -> None:
    assert settle("pose", "a", [_j("a", "ok", 9), _j("b", "failed", 1)]).status == PROVEN
    both = settle("pose", "a", [_j("a", "ok", 5), _j("b", "ok", 9)])
    assert (both.status, both.kept) == (PROVEN, "a")  # the geometry agrees: the evidence decides
    assert "agree too" in both.summary()
    sw = settle("pose", "a", [_j("a", "failed", 1), _j("b", "ok", 5), _j("c", "ok", 8)])
    assert (sw.status, sw.kept) == (SWITCHED, "c") and "SWITCHED from a to c" in sw.summary()
    assert [c.name for c in sw.candidates] == ["c", "a", "b"]
    un = settle("pose", "a", [_j("a", "inconclusive"), _j("b", "failed", 1)])
    assert (un.status, un.kept) == (UNPROVEN, "a")
    assert settle("pose", "a", [_j("a", "failed", 1), _j("b", "inconclusive")]).status == DISAGREES


@pytest.fixture(scope="module")
def wheels(tmp_path_factory: pytest.TempPathFactory) -> tuple[Inspection, ProofReport]:
    ins = inspect_recording(variant(tmp_path_factory, "tf_wheels"))
    return ins, prove(ins)[0]


def test_tf_wheels_wheel_edges_fail_and_the_odom_edge_is_ok(
        wheels: tuple[Inspection, ProofReport]) -> None:  # fmt: skip
    ins, report = wheels
    pose = report.of("pose")
    assert pose is not None and (pose.status, pose.kept) == (PROVEN, ODOM)
    got = {c.name: c for c in pose.candidates}
    assert got[ODOM].verdict == "ok" and got[ODOM].z is not None and got[ODOM].z > 4
    for w in WHEELS:
        assert got[w].verdict == "failed", got[w]
        assert got[w].score is not None and got[ODOM].score is not None
        assert got[w].score < got[ODOM].score / 4
    line = next(x for x in decision_lines(ins, report) if x.startswith("pose:"))
    assert "| geometry: proven" in line and "wheel_left_link failed (score" in line
    assert not report.disagrees and report.seconds > 0


@pytest.mark.slow
def test_a_wrong_evidence_pick_is_switched_and_written(
        wheels: tuple[Inspection, ProofReport]) -> None:  # fmt: skip
    ins, _ = wheels
    pose = next(d for d in ins.decisions if d.what == "pose")
    wheel = next(c for c in pose.candidates if c.name == WHEELS[0])
    wrong = dataclasses.replace(pose, chosen=wheel.name, candidates=(
        wheel, *[c for c in pose.candidates if c is not wheel]))
    ins = dataclasses.replace(ins, decisions=tuple(
        wrong if d is pose else d for d in ins.decisions))  # fmt: skip
    report, fixed = prove(ins)
    proof = report.of("pose")
    assert proof is not None and (proof.status, proof.evidence, proof.kept) == (
        SWITCHED, WHEELS[0], ODOM)
    cfg, _ = build_config(fixed, Path(ins.path))
    assert (cfg.ingest.topics.odom_frame, cfg.ingest.topics.base_frame) == ("odom", "base")


@pytest.mark.slow
def test_an_image_frame_id_of_another_camera_is_switched_to_the_right_frame(
        tmp_path_factory: pytest.TempPathFactory) -> None:  # fmt: skip
    ins = inspect_recording(restamped(tmp_path_factory, "image_says_left",
                                      {FRONT: "hdr_left"}))  # fmt: skip
    cam = next(d for d in ins.decisions if d.what == f"camera {FRONT}")
    assert cam.chosen == "hdr_left" and cam.ambiguous  # the evidence alone takes the image's
    report, fixed = prove(ins)
    proof = report.of(f"camera {FRONT}")
    assert proof is not None and (proof.status, proof.kept) == (SWITCHED, "hdr_front")
    pose = report.of("pose")  # proven again under the switched frame
    assert pose is not None and pose.status == PROVEN
    after = next(d for d in fixed.decisions if d.what == f"camera {FRONT}")
    assert after.chosen == "hdr_front" and not after.ambiguous  # the geometry separated them
    cfg, _ = build_config(fixed, Path(ins.path))
    assert cfg.ingest.topics.frame_of(cfg.ingest.cameras[0]) == "hdr_front"


@pytest.mark.slow
def test_every_candidate_failing_is_said(tmp_path_factory: pytest.TempPathFactory) -> None:
    ins = inspect_recording(restamped(tmp_path_factory, "both_frames_wrong",
                                      {FRONT: "hdr_left", FRONT_INFO: "hdr_right"}))
    report, fixed = prove(ins)
    assert f"camera {FRONT}" in [p.what for p in report.disagrees]
    proof = report.of(f"camera {FRONT}")
    assert proof is not None and proof.kept == "hdr_left"  # the evidence's, written
    assert "geometry disagrees for every candidate" in proof.summary()
    assert fixed.decisions == ins.decisions


@pytest.mark.slow
def test_textureless_views_leave_the_evidence_unproven(
        wheels: tuple[Inspection, ProofReport]) -> None:  # fmt: skip
    ins, _ = wheels
    data = read_proof_data(ins, ["/boxi/hesai/points_undistorted"])
    data.images = {cam: [None if v is None else dataclasses.replace(
        v, grey=np.full_like(v.grey, 128.0)) for v in views]
        for cam, views in data.images.items()}  # fmt: skip
    report, fixed = prove(ins, data)
    assert report.proofs and all(p.status == UNPROVEN for p in report.proofs)
    pose = report.of("pose")
    assert pose is not None and pose.kept == ODOM
    assert all("textureless" in c.reason for c in pose.candidates)
    assert fixed.decisions == ins.decisions


def test_the_config_comments_carry_the_proofs_that_are_no_decision() -> None:
    """A proof without a decision of its own (the point-time convention) is one `# decided`
    line after the decisions: the CLI and the variants bench write the same comments."""
    ins = cast(Inspection, SimpleNamespace(decisions=()))  # only its decisions are read
    timed = Proof("point_time", "last_point", "last_point", PROVEN,
                  (_j("last_point", "ok", 9.0), _j("first_point", "failed", 1.0)))
    lines = decision_lines(ins, ProofReport((timed,), 0.5))
    assert lines == [f"point_time: geometry: {timed.summary()}"]
    assert decision_lines(ins, None) == []
