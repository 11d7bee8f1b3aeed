"""Reject records and the stamp gate that refuses duplicated and out-of-order stamps."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from schemas.recording_index import REJECTS, IndexTableWriter, Reason


@dataclass(frozen=True)
class Reject:
    """One rejected message (or item): where it is, its stamp (ns), why, and details."""

    file: str
    topic: str
    stamp_ns: int
    reason: Reason
    detail: str

    def row(self) -> dict[str, object]:
        """The rejects-table row."""
        return {
            "file": self.file,
            "topic": self.topic,
            "stamp_ns": int(self.stamp_ns),
            "reason": self.reason.value,
            "detail": self.detail,
        }


@dataclass
class RejectLog:
    """Streams rejects to the rejects table and counts them by reason."""

    writer: IndexTableWriter
    counts: Counter[str] = field(default_factory=Counter)

    @classmethod
    def open(cls, path: Path) -> RejectLog:
        """A log writing the rejects table to `path`."""
        return cls(IndexTableWriter(path, REJECTS))

    def add(self, reject: Reject) -> None:
        """Record one reject."""
        self.writer.append(reject.row())
        self.counts[reject.reason.value] += 1

    def close(self) -> None:
        """Finish the table."""
        self.writer.close()


class StampGate:
    """Accepts a topic's messages only in strictly increasing header-stamp order.

    A stamp equal to the last accepted one is a duplicate; a smaller one is out of order.
    Both are refused (the earlier-accepted message is kept), so accepted stamps are sorted
    and unique without buffering.
    """

    def __init__(self) -> None:
        """No stamp accepted yet."""
        self.last: int | None = None

    def check(self, stamp_ns: int) -> tuple[Reason, str] | None:
        """None if `stamp_ns` may be accepted, else (reason, detail)."""
        if self.last is None or stamp_ns > self.last:
            return None
        if stamp_ns == self.last:
            return Reason.DUPLICATE_STAMP, f"stamp {stamp_ns} ns repeats the previous message"
        return (
            Reason.OUT_OF_ORDER_STAMP,
            f"stamp {stamp_ns} ns is {(self.last - stamp_ns) / 1e9:.6f} s before the previous "
            f"accepted stamp {self.last} ns",
        )

    def accept(self, stamp_ns: int) -> None:
        """Mark `stamp_ns` as the last accepted stamp."""
        self.last = stamp_ns
