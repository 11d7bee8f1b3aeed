"""Stamp gate of one topic: refuses duplicated and out-of-order header stamps, notes gaps.

Messages are judged with one message of lookahead, on the raw stamp sequence in reading order:
a message is out of order when its stamp is below the previous message's or above the next
one's (so both messages of a swapped pair are refused: neither stamp can be trusted), and a
duplicate when it repeats the stamp of one of the last `RECENT` messages (the first copy is
kept). A next message that is such a repeat says nothing about the order of the one before it,
so a message re-sent later does not cost its good neighbour. Accepted
stamps are therefore strictly increasing without buffering more than one message. A positive
step between consecutive stamps longer than `GAP_FACTOR` times the running median step is a gap.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

from schemas.recording_index import Reason

GAP_FACTOR = 2.5
"""A stamp step this many times the median step is a gap (10 Hz: 0.25 s, above 3-sigma jitter)."""
RECENT = 64
"""Raw stamps remembered to recognize a re-sent (duplicated) message."""
GAP_HISTORY = 15
"""Steps in the running median; gaps are judged once at least 5 steps are known."""


@dataclass(frozen=True)
class Verdict:
    """A judged message: its payload, stamp (ns), and a reason + detail when refused."""

    item: Any
    stamp_ns: int
    reason: Reason | None = None
    detail: str = ""


@dataclass(frozen=True)
class Gap:
    """A gap in a topic: the last stamp before it, the first after it, and the median step."""

    before_ns: int
    after_ns: int
    median_step_ns: int

    def detail(self) -> str:
        """The gap in one line, as its `stream_gap` reject says it (every source)."""
        span, step = (self.after_ns - self.before_ns) / 1e9, self.median_step_ns / 1e9
        return f"silent {span:.3f} s until {self.after_ns} ns (median step {step:.3f} s)"


class TopicGate:
    """Judges one topic's messages in reading order (see the module docstring)."""

    def __init__(self) -> None:
        """Nothing seen yet."""
        self._held: tuple[Any, int, int | None] | None = None  # item, stamp, previous raw stamp
        self._last_raw: int | None = None
        self._last_ok: int | None = None
        self._steps: deque[int] = deque(maxlen=GAP_HISTORY)
        self._recent: deque[int] = deque(maxlen=RECENT)
        self.gaps: list[Gap] = []

    def push(self, stamp_ns: int, item: Any) -> list[Verdict]:
        """Take the next message; returns the verdict on the previously held one (if any)."""
        repeat = stamp_ns in self._recent
        out = [] if self._held is None else [self._judge(self._held, None if repeat else stamp_ns)]
        if self._held is not None:
            self._recent.append(self._held[1])
        self._note_step(stamp_ns)
        self._held = (item, stamp_ns, self._last_raw)
        self._last_raw = stamp_ns
        return out

    def flush(self) -> list[Verdict]:
        """Verdict on the held message at the end of the stream."""
        held, self._held = self._held, None
        return [] if held is None else [self._judge(held, None)]

    def accepted(self, stamp_ns: int) -> None:
        """Record that a message passed on by the gate was also accepted by its handler."""
        self._last_ok = stamp_ns

    def _judge(self, held: tuple[Any, int, int | None], next_ns: int | None) -> Verdict:
        """Refuse duplicates and out-of-order stamps; accept the rest."""
        item, stamp, prev = held
        if stamp in self._recent:
            return Verdict(item, stamp, Reason.DUPLICATE_STAMP,
                           f"stamp {stamp} ns repeats an earlier message's")  # fmt: skip
        if prev is not None and stamp < prev:
            return Verdict(item, stamp, Reason.OUT_OF_ORDER_STAMP,
                           f"stamp {stamp} ns is {(prev - stamp) / 1e9:.6f} s before the previous "
                           f"message's {prev} ns")  # fmt: skip
        if next_ns is not None and stamp > next_ns:
            return Verdict(item, stamp, Reason.OUT_OF_ORDER_STAMP,
                           f"stamp {stamp} ns is {(stamp - next_ns) / 1e9:.6f} s after the next "
                           f"message's {next_ns} ns")  # fmt: skip
        if self._last_ok is not None and stamp <= self._last_ok:
            detail = f"stamp {stamp} ns is not after the last accepted {self._last_ok} ns"
            return Verdict(item, stamp, Reason.OUT_OF_ORDER_STAMP, detail)
        return Verdict(item, stamp)

    def _note_step(self, stamp_ns: int) -> None:
        """Track positive steps between consecutive raw stamps and record gaps."""
        if self._last_raw is None or stamp_ns <= self._last_raw:
            return
        step = stamp_ns - self._last_raw
        if len(self._steps) >= 5:
            median = sorted(self._steps)[len(self._steps) // 2]
            if step > GAP_FACTOR * median:
                self.gaps.append(Gap(self._last_raw, stamp_ns, median))
                return  # a gap does not enter the step history
        self._steps.append(step)
