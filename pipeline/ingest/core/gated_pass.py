"""The ingest core: one gated-stream pass for every source, stamped raw records in, index rows,
rejects and check rows out.

A source feeds each of its streams as `Record`s in stream order: an ordinal (row, frame), a
stamp (int64 ns, or a `RowReject` saying why the record has no usable stamp) and a payload.
The HF Zarr layout and KITTI-360 run one pass per topic group or sensor folder to its end
(`run`); the bags (`core.stream`) push each topic's messages, across the bags, into that
topic's pass (`push`, `end_gate` per bag, `end_checks` at the end). The pass runs:

- the stamp gate (`checks.gate.TopicGate`): duplicate and out-of-order stamps refused, each gap
  one `stream_gap` reject with the bag path's wording;
- the source's handler: decode the payload into an index row (`Indexed`) or refuse it
  (`RowReject`: missing file, corrupt image, empty sweep, corrupt points, bad pose);
- the plausibility checks, fitted to the stream (`checks.check_fit.FitGate`): sweeps by
  `checks.sweep_checks` (SWEEP_CHECKS), poses by the jump filter and the quaternion norm
  (`checks.pose_checks`, POSE_CHECKS), images by the drift check against their neighbouring
  frames (`checks.image_drift`, IMAGE_CHECKS: each image held until the next is decoded); a
  sweep they refuse is `bad_pointcloud`, a pose `bad_pose`, an image `corrupt_jpeg`, with the
  bag path's detail;
- the accounting: every record read is counted, kept (an index row) or rejected (a reject row).

`check_rows` and `check_notes` gather the checks of every pass for the checks table and the
warnings, ordered by topic.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from packets.poses import F64
from pipeline.ingest.checks.check_fit import FitGate, Release
from pipeline.ingest.checks.gate import TopicGate, Verdict
from pipeline.ingest.checks.image_checks import Cells
from pipeline.ingest.checks.image_drift import IMAGE_CHECKS, DriftHold, drift_on
from pipeline.ingest.checks.pose_checks import POSE_CHECKS, JumpFilter, PoseVerdict
from pipeline.ingest.checks.rejects import Reject, Tally
from pipeline.ingest.checks.sweep_checks import SWEEP_CHECKS
from pipeline.ingest.core.sinks import CameraImage, ImageSink, Writers
from pipeline.ingest.errors import RowReject
from schemas.config import ChecksConfig
from schemas.recording_index import IndexTableWriter, Reason


class Record(NamedTuple):
    """One stamped raw record of a stream: ordinal (row, frame), stamp (int64 ns, or why the
    record has no usable stamp), the payload its handler decodes; for a stream read across
    files (bags) the file it was read from and the time (ns) a record without a usable stamp
    is rejected at (its log time)."""

    ordinal: int
    stamp: int | RowReject
    payload: Any = None
    file: str = ""
    at: int = 0


class Indexed(NamedTuple):
    """A record its handler decoded: the index row, the file it lives in (named by a check's
    reject), the plausibility verdicts of its checks (check -> None or one line), an image's
    cells for the drift check (None: not judged by it) and what is done when the record is
    kept (`emit`: hands it on, returns the columns it fills, e.g. an image's frame number)."""

    row: dict[str, object]
    file: str
    problems: Mapping[str, str | None] = {}
    cells: Cells | None = None
    emit: Callable[[], Mapping[str, object]] | None = None
    trusted: bool = False


class Held:
    """A handler's answer for a record it accepted and holds (decided later: `GatedPass.check`)."""


HELD = Held()


Handler = Callable[[int, int, Any], Indexed | Held | None]
"""(ordinal, stamp ns, payload) -> the decoded record, HELD (accepted, handed to the checks
later) or None (nothing to index, not accepted); raises RowReject."""

KINDS: dict[str, tuple[tuple[str, ...], Reason]] = {
    "sweep": (SWEEP_CHECKS, Reason.BAD_POINTCLOUD),
    "pose": (POSE_CHECKS, Reason.BAD_POSE),
    "image": (IMAGE_CHECKS, Reason.CORRUPT_JPEG),
}
"""Which records have plausibility checks: their check names and their reject reason."""


@dataclass
class GatedPass:
    """One stream through the stamp gate, its handler and its checks into one index table.

    topic: the stream's name in rejects and checks; key: its accounting key (file, topic);
    where: the file named by stamp refusals and gaps; table: the index table it appends to;
    kind: "sweep", "pose", "image" or "" (no plausibility checks); number: a column numbering
    the rows kept (`sweep`), filled when a row is appended; checks: the config (None: none);
    unit: what an ordinal counts, in a stamp refusal's detail ("row", "frame"); spans_files:
    the stream is read across files (bags): each record is accounted by (its file, topic) (the
    handler's `Indexed.file` is the record's file), a refusal names its file, and rejects are
    counted by the reject log (`tally` is its tally).
    Its checks are made when a record first reaches them (`fitted`); `end_gate`, `end_holds`,
    `end_jumps` and `end_checks` end a file's or the recording's stream in the caller's order.
    """

    out: Writers
    topic: str
    key: tuple[str, str]
    where: str
    table: IndexTableWriter
    tally: Tally
    kind: str = ""
    number: str = ""
    checks: ChecksConfig | None = None
    unit: str = "row"
    spans_files: bool = False
    gate: TopicGate = field(default_factory=TopicGate)
    on: bool = False
    checked: FitGate | None = None
    jumps: JumpFilter | None = None
    drift: DriftHold | None = None
    handle: Handler | None = None

    def __post_init__(self) -> None:
        """The plausibility checks of this stream, when its kind has some and they are on."""
        c = self.checks
        self.on = self.kind in KINDS and c is not None and c.enabled and (
            self.kind != "image" or drift_on(c))  # fmt: skip
        if not self.on or c is None:
            return
        if self.kind == "pose":
            self.jumps = JumpFilter(c.max_speed_m_s)
        if self.kind == "image":
            self.drift = DriftHold(c, lambda _: self.fitted().active("image_drift"))

    @property
    def fit(self) -> FitGate | None:
        """The stream's fitted checks (made now if they are on), None when they are off."""
        return self.fitted() if self.on else None

    def fitted(self) -> FitGate:
        """The stream's fitted checks, made on first use."""
        if self.checked is None:
            c = self.checks or ChecksConfig()
            self.checked = FitGate(self.topic, KINDS[self.kind][0], c.calibration_messages,
                                   c.max_reject_share)  # fmt: skip
        return self.checked

    def run(self, records: Iterable[Record], handle: Handler) -> None:
        """Gate every record (in stream order), index accepted ones, record the rest."""
        self.handle = handle
        for rec in records:
            self.push(rec)
        self.end_gate(self.where)
        self.end_jumps()
        self.end_holds()
        self.end_checks()

    def push(self, rec: Record) -> None:
        """Count one record read and pass it through the stamp gate (`handle` decodes it)."""
        self.tally.read[self._key(rec.file)] += 1
        if isinstance(rec.stamp, RowReject):
            err = rec.stamp
            self.drop(err.file, rec.at, err.reason, str(err))
            return
        for verdict in self.gate.push(rec.stamp, (rec.ordinal, rec.payload, rec.file)):
            self._judge(verdict)

    def end_gate(self, where: str) -> None:
        """The end of a file or stream: judge the record the gate holds; each gap one
        `stream_gap` reject naming `where`."""
        for verdict in self.gate.flush():
            self._judge(verdict)
        for gap in self.gate.gaps:
            self.out.rejects.add(Reject(where, self.topic, gap.before_ns, Reason.STREAM_GAP,
                                        gap.detail()))
        self.gate.gaps.clear()

    def end_jumps(self) -> None:
        """Judge the poses the jump filter holds."""
        if self.jumps is not None:
            for v in self.jumps.flush():
                self._pose(v)

    def end_holds(self) -> None:
        """Judge the image the drift check holds against the last accepted one."""
        if self.drift is not None:
            for (at, held), problem in self.drift.flush():
                self._fit(at, held, {"image_drift": problem})

    def end_checks(self) -> None:
        """The end of the recording: release every record the fitted checks still hold."""
        if self.checked is not None:
            for rel in self.checked.flush():
                self._release(rel)

    def _judge(self, verdict: Verdict) -> None:
        """Record a refused record, else decode it and hand it to the checks."""
        ordinal, payload, file = verdict.item
        if verdict.reason is not None:
            if self.spans_files:
                self.drop(file, verdict.stamp_ns, verdict.reason, verdict.detail)
            else:
                self.drop(self.where, verdict.stamp_ns, verdict.reason,
                          f"{self.where} {self.unit} {ordinal}: {verdict.detail}")  # fmt: skip
            return
        assert self.handle is not None
        try:
            done = self.handle(ordinal, verdict.stamp_ns, payload)
        except RowReject as err:
            self.drop(err.file, verdict.stamp_ns, err.reason, str(err))
            return
        if done is None:
            return
        self.gate.accepted(verdict.stamp_ns)
        if isinstance(done, Indexed):
            self.check(verdict.stamp_ns, done)

    def check(self, stamp: int, done: Indexed) -> None:
        """Hand a decoded record to its checks (the drift hold first for an image, the jump
        filter first for a pose); a record they hold is released later."""
        if not self.on:
            self._release(Release((stamp, done)))
            return
        if self.drift is not None:
            hold = self.drift
            judged = hold.pop(self.topic) if done.cells is None else (
                hold.push(self.topic, (stamp, done), done.cells))  # fmt: skip
            for (at, held), problem in judged:
                self._fit(at, held, {"image_drift": problem})
            if done.cells is None:  # not judged by the drift check (no cells to judge)
                self._fit(stamp, done, {}, trusted=True)
            return
        if self.jumps is None:
            self._fit(stamp, done, done.problems, done.trusted)
            return
        position = np.asarray(done.row["position"], dtype=np.float64)
        for v in self.jumps.push(stamp, position, done, judge=not done.trusted):
            self._pose(v)

    def _pose(self, v: PoseVerdict) -> None:
        """A pose judged by the jump filter, to its stream's checks."""
        done: Indexed = v.item
        self._fit(v.stamp_ns, done, {**done.problems, "pose_jump": v.problem}, done.trusted)

    def _fit(self, stamp: int, done: Indexed, problems: Mapping[str, str | None],
             trusted: bool = False) -> None:  # fmt: skip
        """One record through the fitted checks; release what they let go."""
        fit = self.fitted()
        active = {c: p for c, p in problems.items() if c in fit.records}
        for rel in fit.push((stamp, done), active, trusted):
            self._release(rel)

    def _key(self, file: str) -> tuple[str, str]:
        """The accounting key of a record read from `file`."""
        return (file, self.topic) if self.spans_files else self.key

    def _release(self, rel: Release) -> None:
        """Index a record let go by the checks, or reject it with the bag path's detail."""
        stamp, done = rel.item
        if rel.rejected_by is not None:
            check, problem = rel.rejected_by
            detail = f"{problem} ({check}): a damaged message" if self.kind == "sweep" else problem
            self.drop(done.file, stamp, KINDS[self.kind][1], detail)
            return
        row = {self.number: self.table.count, **done.row} if self.number else done.row
        if done.emit is not None:
            row = {**row, **done.emit()}
        self.table.append(row)
        self.tally.kept[self._key(done.file)] += 1

    def drop(self, file: str, stamp: int, reason: Reason, detail: str) -> None:
        """Record a reject of one record that was read (counted rejected in the accounting:
        by the reject log itself for a stream across files)."""
        self.out.rejects.add(Reject(file, self.topic, stamp, reason, detail))
        if not self.spans_files:
            self.tally.rejected[self.key] += 1

    def location(self, ordinal: int, stamp: int, file: str) -> dict[str, object]:
        """The location columns of an index row (the layout has no log time: the stamp)."""
        return {"file": file, "topic": self.topic, "bag_time_ns": stamp, "ordinal": ordinal}


def emit_image(camera: str, stamp: int, image: npt.NDArray[np.uint8], K_out: F64,
               sink: ImageSink | None, frames: dict[str, int]) -> Callable[[], dict[str, object]]:
    """What keeping one output image does: number it among its camera's kept images
    (`frames`, counted on), hand it to the sink (RGB (out_h, out_w, 3) with its intrinsics
    `K_out` (3, 3)) and fill its index row's `frame`."""

    def emit() -> dict[str, object]:
        frame = frames.get(camera, 0)
        frames[camera] = frame + 1
        if sink is not None:
            sink(CameraImage(camera, frame, stamp, image, K_out))
        return {"frame": frame}

    return emit


def check_rows(passes: Iterable[GatedPass]) -> list[dict[str, object]]:
    """Checks-table rows of every pass that ran checks, by topic (as the bag path)."""
    fits = {p.topic: p.checked for p in passes if p.checked is not None}
    return [row for topic in sorted(fits) for row in fits[topic].rows()]


def check_notes(passes: Iterable[GatedPass]) -> list[str]:
    """The warnings of the checks (one per check switched off or capped), by topic."""
    fits = {p.topic: p.checked for p in passes if p.checked is not None}
    return [n for topic in sorted(fits) for n in fits[topic].notes]
