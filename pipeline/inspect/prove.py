"""Inspect proves its configuration: every decision judged by the geometry it implies.

For the pose source, then each camera's frame, then the reference LiDAR (in that order, each
with the ones settled before it), the candidates of the decision (at most `MAX_CANDIDATES`,
the evidence's order; again while a pass switches one: `MAX_PASSES`) are judged by the
run's geometry check on a few views (`prove_read`, `prove_judge`); a decision with one
candidate is judged once (its config's geometry). `settle` keeps or changes the evidence's pick:

- `proven`: the evidence's pick is `ok` (another `ok` is named: the geometry does not
  separate them, the evidence decides);
- `switched`: the evidence's pick is not `ok` and another candidate is: the best-scoring `ok`
  one is taken, said loudly;
- `unproven`: no candidate is `ok` and the pick is not `failed` (textureless, static, too few
  views, a frame the tree lacks): the evidence's pick stays, with why;
- `disagrees`: the pick `failed` and no candidate is `ok`: the config is written, the command
  exits non-zero unless `--no-verify`.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from packets.geometry_verdict import FAILED, OK
from pipeline.inspect.model import Candidate, Decision, Inspection
from pipeline.inspect.prove_judge import Judged, Rig, Unjudged, judge_rig, judged
from pipeline.inspect.prove_kitti360 import fixed_decisions
from pipeline.inspect.prove_read import ProofData
from pipeline.inspect.prove_source import read_proof_data
from pipeline.inspect.prove_time import TimeJudgement, judge_time, reference_of
from schemas.errors import DataError

MAX_CANDIDATES = 4
"""Candidates of one decision judged at most (the evidence's first)."""
MAX_PASSES = 3
"""Passes over the decisions at most: a decision switched in one pass changes the rig the
others are judged under (a wrong camera frame fails every pose candidate), so they are
proven again, until a pass changes nothing."""
PROVEN, SWITCHED, UNPROVEN, DISAGREES = "proven", "switched", "unproven", "disagrees"
Z_SEPARATE = 3.0
"""Two point-time readings that both pass the null test are told apart when their z differ
by at least this (`settle_time`)."""


@dataclass(frozen=True)
class Proof:
    """One decision proven: the evidence's pick, the candidate kept, the status (module
    docstring) and every candidate judged (the kept one first)."""

    what: str
    evidence: str
    kept: str
    status: str
    candidates: tuple[Judged, ...]
    note: str = ""

    def summary(self) -> str:
        """The proof in one line: status, what was kept, each candidate's verdict and score;
        `note` (why it is unproven, or what the judgement rests on) after the status."""
        kept = f"{self.kept} kept on the evidence" if self.kept else ""
        head = {PROVEN: f"proven: {self.kept} agrees with the images",
                SWITCHED: f"SWITCHED from {self.evidence} to {self.kept}: the evidence's pick "
                          "disagrees with the images",
                UNPROVEN: f"unproven: {self.note}; {kept}" if self.note else f"unproven: {kept}",
                DISAGREES: "geometry disagrees for every candidate"}[self.status]  # fmt: skip
        also = [c for c in self.candidates[1:] if c.verdict == OK]
        if self.status == PROVEN and also:
            head += (f" ({len(also)} other candidate(s) agree too: the geometry does not "
                     "separate them, the evidence decides)")
        if self.note and self.status != UNPROVEN:
            head += f" ({self.note})"
        return "; ".join([head.rstrip("; "), *(c.short() for c in self.candidates)])

    def line(self) -> str:
        """`geometry <what>: <summary>`."""
        return f"geometry {self.what}: {self.summary()}"


@dataclass(frozen=True)
class ProofReport:
    """Every decision's proof, the seconds it took (reading and judging) and what could not
    be read."""

    proofs: tuple[Proof, ...]
    seconds: float
    problems: tuple[str, ...] = ()

    @property
    def disagrees(self) -> list[Proof]:
        """The decisions whose every candidate failed."""
        return [p for p in self.proofs if p.status == DISAGREES]

    def of(self, what: str) -> Proof | None:
        """The proof of decision `what`, or None."""
        return next((p for p in self.proofs if p.what == what), None)

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-compatible data."""
        return {"seconds": round(self.seconds, 3), "problems": list(self.problems),
                "decisions": [asdict(p) | {"line": p.line()} for p in self.proofs]}


def settle(what: str, evidence: str, results: list[Judged]) -> Proof:
    """The decision after its candidates' geometry (module docstring); `evidence` the
    evidence's pick among `results`."""
    pick = next((r for r in results if r.name == evidence), None)
    oks = sorted((r for r in results if r.verdict == OK), key=lambda r: -(r.z or 0.0))
    if pick is not None and pick.verdict == OK:
        status, kept = PROVEN, pick
    elif oks:
        status, kept = SWITCHED, oks[0]
    else:
        status = DISAGREES if pick is not None and pick.verdict == FAILED else UNPROVEN
        kept = pick or results[0]
    order = (kept, *[r for r in results if r is not kept])
    return Proof(what, evidence, kept.name, status, order)


class Prover:
    """Judges rigs on one recording's proof data, each rig once."""

    def __init__(self, data: ProofData, cameras: list[str]) -> None:
        self.data = data
        self.cameras = cameras
        self._done: dict[str, Judged] = {}

    def judge(self, name: str, rig: Rig, cameras: list[str] | None = None) -> Judged:
        """The candidate `name` judged under `rig` over `cameras` (all when None)."""
        cams = self.cameras if cameras is None else cameras
        key = rig.key() + repr(cams)
        if key not in self._done:
            try:
                self._done[key] = judged(name, judge_rig(self.data, rig, cams))
            except Unjudged as err:
                self._done[key] = Judged(name, "inconclusive", None, None, str(err))
        return replace(self._done[key], name=name)


def _candidates(d: Decision) -> list[Candidate]:
    """The candidates of `d` judged: usable, with keys, at most MAX_CANDIDATES."""
    return [c for c in d.candidates if c.usable and c.keys][:MAX_CANDIDATES]


def _base_rig(ins: Inspection) -> Rig | None:
    """The rig of the evidence's picks (None without a pose source or a LiDAR)."""
    by = {d.what: d for d in ins.decisions}
    pose, lidar = by.get("pose"), by.get("lidar")
    if pose is None or lidar is None or not pose.chosen or not lidar.chosen:
        return None
    frames = {d.what.removeprefix("camera "): d.chosen for d in ins.decisions
              if d.what.startswith("camera ") and d.chosen}  # fmt: skip
    return Rig(dict(pose.keys), lidar.chosen, str(lidar.keys.get("frame", "")), frames)


def _prove_one(p: Prover, d: Decision, rig: Rig) -> tuple[Proof, Rig]:
    """One decision's proof and the rig with its kept candidate."""
    cands = _candidates(d)
    if not cands:
        return Proof(d.what, d.chosen, d.chosen, UNPROVEN, (Judged(
            d.chosen, "inconclusive", None, None, "no candidate with keys"),)), rig
    results = []
    for c in cands:
        if d.what == "pose":
            r, cams = replace(rig, pose=dict(c.keys)), None
        elif d.what == "lidar":
            r, cams = replace(rig, lidar=c.name, lidar_frame=str(c.keys.get("frame", ""))), None
        else:
            topic = d.what.removeprefix("camera ")
            r, cams = replace(rig, frames={**rig.frames, topic: c.name}), [topic]
        results.append((p.judge(c.name, r, cams), r))
    proof = settle(d.what, d.chosen, [j for j, _ in results])
    return proof, next(r for j, r in results if j.name == proof.kept)


def prove(ins: Inspection, data: ProofData | None = None) -> tuple[ProofReport, Inspection]:
    """Every decision of `ins` proven (module docstring) and the inspection with the switched
    decisions changed (the kept candidate chosen, first); `data`: the views to judge on (read
    from the recording when None)."""
    began = time.perf_counter()
    given = ins
    if not ins.decisions:  # a layout that leaves no choice (KITTI-360): its one rig is judged
        ins = replace(ins, decisions=fixed_decisions(ins))
    rig = _base_rig(ins)
    if rig is None:
        why = "no pose source or LiDAR decided"
        return ProofReport((), time.perf_counter() - began, (why,)), ins
    lidar = next(d for d in ins.decisions if d.what == "lidar")
    topics = [c.name for c in lidar.candidates if c.usable]
    if data is None:
        data = read_proof_data(ins, [rig.lidar, *[t for t in topics if t != rig.lidar]])
    cams = [c for c in rig.frames if data.images.get(c)]
    rig = replace(rig, frames={c: rig.frames[c] for c in cams})
    prover = Prover(data, cams)
    order = ([d for d in ins.decisions if d.what == "pose"]
             + [d for d in ins.decisions if d.what.removeprefix("camera ") in cams]
             + [lidar])  # fmt: skip
    proofs: list[Proof] = []
    for _ in range(MAX_PASSES):  # a switch proves the others again under it
        proofs, start = [], rig
        for d in order:
            proof, rig = _prove_one(prover, d, rig)
            proofs.append(proof)
        if rig == start:
            break
    if any(p.status == DISAGREES for p in proofs):
        proofs.append(Proof(f"point_time {rig.lidar}", "", "", UNPROVEN, (),
                            "the rig's geometry disagrees already: the convention cannot be "
                            "judged under it"))  # fmt: skip
    else:
        proofs.append(prove_time(data, ins, rig, cams))
    report = ProofReport(tuple(proofs), time.perf_counter() - began, tuple(data.problems))
    return report, replace(_time_switched(given, proofs[-1], rig.lidar),
                           decisions=tuple(_switched(d, report) for d in given.decisions))


def _time_switched(ins: Inspection, proof: Proof, lidar: str) -> Inspection:
    """`ins` with the reference LiDAR's point-time reference the proof switched to (what the
    configuration then declares); unchanged unless the point-time proof switched it."""
    ref = reference_of(proof.kept)
    cloud = next((c for c in ins.clouds if c.topic == lidar), None)
    if proof.status != SWITCHED or cloud is None or ref == cloud.convention.reference:
        return ins
    conv = replace(cloud.convention, reference=ref, decided_by=(
        f"geometry over {cloud.convention.reference} ({cloud.convention.decided_by})"))
    return replace(ins, clouds=tuple(replace(c, convention=conv) if c is cloud else c
                                     for c in ins.clouds))  # fmt: skip


def prove_time(data: ProofData, ins: Inspection, rig: Rig, cams: list[str]) -> Proof:
    """The reference LiDAR's point-time convention proven under the settled rig
    (`prove_time`): settled as every decision, except that both readings agreeing is
    `unproven: motion too small to tell`, with the motion over one sweep."""
    return declarable(settle_time(f"point_time {rig.lidar}", judge_time(data, ins, rig, cams)))


def declarable(proof: Proof) -> Proof:
    """`proof` as far as the configuration can declare it: a switch between two readings of
    one reference (`absolute` times, whose header end is measured, not declared) is
    unproven, the evidence's reading kept, saying what the images favoured."""
    if proof.status != SWITCHED or reference_of(proof.kept) != reference_of(proof.evidence):
        return proof
    return replace(proof, status=UNPROVEN, kept=proof.evidence, note=(
        f"the images favour {proof.kept}, which {reference_of(proof.evidence)} point times "
        f"cannot declare; {proof.note}"))


def settle_time(what: str, got: TimeJudgement | str) -> Proof:
    """The point-time decision after its readings' geometry: `settle`, except when both
    readings pass the null test (`_both_ok`: told apart by their z, or `unproven: motion too
    small to tell (X mm, Y deg per sweep; azimuth step Z deg)`); a judgement that could not
    be made (`got` the reason) is unproven with it."""
    if isinstance(got, str):
        return Proof(what, "", "", UNPROVEN, (), got)
    if all(r.verdict == OK for r in got.results):
        return _both_ok(what, got)
    proof = settle(what, got.inferred, list(got.results))
    return replace(proof, note=f"the robot moves {got.motion()}")


def _both_ok(what: str, got: TimeJudgement) -> Proof:
    """Both readings pass the null test: the one whose z exceeds the other's by `Z_SEPARATE`
    or more is kept (the same views, images and null: their mean scores differ by that many
    of the null's standard deviations), else `unproven: motion too small to tell`."""
    a, b = got.results[0], got.results[1]
    dz = (a.z or 0.0) - (b.z or 0.0)
    if abs(dz) < Z_SEPARATE:
        return Proof(what, a.name, a.name, UNPROVEN, got.results,
                     f"motion too small to tell ({got.motion()})")  # fmt: skip
    win, lose = (a, b) if dz > 0 else (b, a)
    return Proof(what, a.name, win.name, PROVEN if win is a else SWITCHED, (win, lose),
                 f"both agree with the images, {win.name} by z {abs(dz):.1f}; the robot "
                 f"moves {got.motion()}")  # fmt: skip


def _switched(d: Decision, report: ProofReport) -> Decision:
    """`d` as the proof leaves it: the kept candidate chosen (first) when the proof switched
    it; no longer ambiguous when the geometry separated the candidates (the kept one `ok`,
    every other judged one `failed`)."""
    proof = report.of(d.what)
    if proof is None:
        return d
    others = proof.candidates[1:]
    separated = (proof.status in (PROVEN, SWITCHED) and bool(others)
                 and all(c.verdict == FAILED for c in others))  # fmt: skip
    if proof.status != SWITCHED:
        if not (d.ambiguous and separated):
            return d
        return replace(d, ambiguous=False, reason=f"{d.reason}; the geometry separates them")
    kept = [c for c in d.candidates if c.name == proof.kept]
    return replace(d, chosen=proof.kept, candidates=(*kept, *[c for c in d.candidates
                                                              if c.name != proof.kept]),
                   ambiguous=d.ambiguous and not separated,
                   reason=f"chosen by geometry over {proof.evidence} ({d.reason})")


def prove_or_say(ins: Inspection, recording: Path) -> tuple[ProofReport, Inspection]:
    """`prove(ins)`, or, for a recording the proof cannot read, every decision kept unproven
    with the one line saying why (what `inspect --write-config` and the variants bench do)."""
    try:
        return prove(ins)
    except (DataError, OSError, ValueError) as err:
        return ProofReport((), 0.0, (f"{recording}: the decisions cannot be proven: {err}",)), ins
