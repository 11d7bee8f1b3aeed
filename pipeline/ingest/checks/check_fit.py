"""Plausibility checks that fit themselves to the stream, and may never reject much of it.

Every plausibility check (sweep limits, ring elevations, rotation, quaternion norm, pose jumps,
image drift) encodes a model of a sensor. A stream the model does not describe (rings numbered
otherwise, a non-repetitive scan, another odometry rate) would have most of its messages found
implausible: the check is wrong about the stream, not the stream wrong. So, per topic:

- calibration: the first `calibration_messages` messages are judged by every check but held
  (their verdicts buffered, nothing rejected). A check that finds more of them implausible than
  its allowance is switched off for the topic (`off`), with one warning naming the topic, the
  check and the measured misfit; the held messages are then released with the verdicts of the
  checks that stay on;
- a cap: a check rejects a message only while its rejects stay within its allowance,
  max(1, floor(`max_reject_share` x messages judged)). Past it the check stops rejecting
  (`capped`), the messages are kept, and the run says "check X does not fit topic T".

One allowance of a single message lets a check catch one damaged message in a short stream;
otherwise no check rejects more than the configured share of a stream. Pure bookkeeping: the
checks themselves live in `sweep_checks`, `pose_checks` and `image_checks`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple


def allowance(messages: int, max_share: float) -> int:
    """Rejects a check may make over `messages` judged messages: max(1, floor(share x n))."""
    return max(1, int(max_share * messages + 1e-9))


@dataclass
class CheckRecord:
    """One check on one topic: state (`calibrating`, `on`, `off`, `capped`), messages judged,
    messages found implausible (`flagged`), messages rejected, and a one-line detail."""

    topic: str
    check: str
    state: str = "calibrating"
    messages: int = 0
    flagged: int = 0
    rejected: int = 0
    trusted: int = 0
    detail: str = ""
    first_problem: str = ""

    def row(self) -> dict[str, object]:
        """The checks-table row (`schemas.recording_index.CHECKS`)."""
        detail = self.detail or (f"first: {self.first_problem}" if self.first_problem else "")
        return {"topic": self.topic, "check": self.check, "state": self.state,
                "messages": self.messages, "flagged": self.flagged, "rejected": self.rejected,
                "trusted": self.trusted, "detail": detail}  # fmt: skip


class Release(NamedTuple):
    """A message let go by the gate: its payload, and (check, problem) when it is rejected."""

    item: Any
    rejected_by: tuple[str, str] | None = None


@dataclass
class FitGate:
    """The plausibility checks of one topic (see the module docstring).

    `push` each message with every active check's verdict (None: plausible, else one line);
    it returns the messages decided so far, in stream order. `flush` at the end of the stream.
    `notes` collects the warnings for the user (one per check switched off or capped).
    """

    topic: str
    checks: tuple[str, ...]
    calibration: int = 10
    max_share: float = 0.02
    records: dict[str, CheckRecord] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    _held: list[tuple[Any, Mapping[str, str | None]]] = field(default_factory=list)

    def __post_init__(self) -> None:
        """One record per check."""
        for c in self.checks:
            self.records.setdefault(c, CheckRecord(self.topic, c))

    @property
    def calibrating(self) -> bool:
        """True while the first messages are being held."""
        return any(r.state == "calibrating" for r in self.records.values())

    def active(self, check: str) -> bool:
        """Whether `check` should still be computed (calibrating or on)."""
        return self.records[check].state in ("calibrating", "on")

    def push(self, item: Any, problems: Mapping[str, str | None],
             trusted: bool = False) -> list[Release]:
        """Judge one message by the verdicts of the active checks (inactive ones are ignored);
        a `trusted` message (a verified checksum vouches for it) is judged by none."""
        if trusted:
            problems = {}
            for rec in self.records.values():
                rec.trusted += 1
        problems = {c: p for c, p in problems.items() if self.active(c)}
        for c, p in problems.items():
            rec = self.records[c]
            rec.messages += 1
            if p:
                rec.flagged += 1
                rec.first_problem = rec.first_problem or p
        if self.calibrating:
            self._held.append((item, problems))
            return self._end_calibration() if len(self._held) >= self.calibration else []
        return [self._judge(item, problems)]

    def flush(self) -> list[Release]:
        """Decide on messages still held (a stream shorter than the calibration)."""
        return self._end_calibration() if self.calibrating else []

    def _end_calibration(self) -> list[Release]:
        """Switch off the checks that do not fit; release the held messages."""
        for rec in self.records.values():
            if rec.state != "calibrating":
                continue
            if rec.flagged > allowance(rec.messages, self.max_share):
                rec.state = "off"
                rec.detail = (f"found {rec.flagged} of the first {rec.messages} messages "
                              f"implausible (first: {rec.first_problem})")  # fmt: skip
                self.notes.append(f"check {rec.check} does not fit topic {self.topic}: it "
                                  f"{rec.detail}; switched off for this topic")  # fmt: skip
            else:
                rec.state = "on"
        held, self._held = self._held, []
        return [self._judge(item, problems) for item, problems in held]

    def _judge(self, item: Any, problems: Mapping[str, str | None]) -> Release:
        """Reject by the first check that is on, flags the message and has allowance left."""
        out = None
        for c, p in problems.items():
            rec = self.records[c]
            if p is None or rec.state != "on":
                continue
            if rec.rejected + 1 > allowance(rec.messages, self.max_share):
                rec.state = "capped"
                rec.detail = (f"stopped rejecting: it found {rec.flagged} of {rec.messages} "
                              f"messages implausible, more than {self.max_share:.1%} "
                              f"(first: {rec.first_problem})")  # fmt: skip
                self.notes.append(f"check {c} does not fit topic {self.topic}: it {rec.detail}; "
                                  "the messages are kept")  # fmt: skip
                continue
            if out is None:
                out = (c, p)
                rec.rejected += 1
        return Release(item, out)

    def rows(self) -> list[dict[str, object]]:
        """Checks-table rows of this topic."""
        return [r.row() for r in self.records.values()]
