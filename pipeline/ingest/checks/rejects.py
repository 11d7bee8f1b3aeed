"""Reject records, the reject log (the rejects table, counted by reason) and the accounting.

The accounting counts, per bag file and topic, messages read, kept (an index row) and rejected
(a reject row naming the message); `read == kept + rejected` is the invariant the tests check.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from schemas.recording_index import MESSAGE_REASONS, REJECTS, IndexTableWriter, Reason


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
class Tally:
    """Messages read, kept and rejected, per (bag file, topic)."""

    read: Counter[tuple[str, str]]
    kept: Counter[tuple[str, str]]
    rejected: Counter[tuple[str, str]]

    @classmethod
    def empty(cls) -> Tally:
        """Nothing counted yet."""
        return cls(Counter(), Counter(), Counter())

    def rows(self) -> list[dict[str, object]]:
        """Accounting-table rows, one per (file, topic) read."""
        return [{"file": f, "topic": t, "read": self.read[(f, t)], "kept": self.kept[(f, t)],
                 "rejected": self.rejected[(f, t)]} for f, t in sorted(self.read)]  # fmt: skip

    def unaccounted(self) -> dict[tuple[str, str], int]:
        """(file, topic) -> read - kept - rejected, where that is not zero (a silent loss)."""
        out = {}
        for key, n in self.read.items():
            gap = n - self.kept[key] - self.rejected[key]
            if gap:
                out[key] = gap
        return out


NOTABLE = frozenset({Reason.TRUNCATED_BAG, Reason.UNREADABLE_BAG, Reason.MISSING_TOPIC,
                     Reason.MISSING_CAMERA_INFO, Reason.BAD_CAMERA_INFO, Reason.MISSING_TF_EDGE,
                     Reason.DAMAGED_REGION})
"""Reasons that drop a whole bag, topic or camera: told to the user, not only tabled."""


def warning_lines(notable: list[Reject], counts: dict[str, int], table: Path) -> list[str]:
    """One line per notable reject, and one summing up the per-message rejects."""
    lines = [": ".join(p for p in (r.file or "(no bag)", r.topic, r.reason.value, r.detail) if p)
             for r in notable]
    rest = {k: v for k, v in counts.items() if k not in {r.value for r in NOTABLE}}
    if rest:
        parts = ", ".join(f"{k} {v}" for k, v in sorted(rest.items()))
        lines.append(f"{sum(rest.values())} reject record(s) ({parts}); see {table}")
    return lines


@dataclass
class RejectLog:
    """Streams rejects to the rejects table, counts them by reason and per message (tally)."""

    writer: IndexTableWriter
    counts: Counter[str] = field(default_factory=Counter)
    notable: list[Reject] = field(default_factory=list)
    tally: Tally = field(default_factory=Tally.empty)

    @classmethod
    def open(cls, path: Path) -> RejectLog:
        """A log writing the rejects table to `path`."""
        return cls(IndexTableWriter(path, REJECTS))

    def add(self, reject: Reject) -> None:
        """Record one reject."""
        self.writer.append(reject.row())
        self.counts[reject.reason.value] += 1
        if reject.reason in MESSAGE_REASONS:
            self.tally.rejected[(reject.file, reject.topic)] += 1
        if reject.reason in NOTABLE:
            self.notable.append(reject)

    def close(self) -> None:
        """Finish the table."""
        self.writer.close()
