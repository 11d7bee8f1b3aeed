"""Reject records and the reject log (the rejects table, counted by reason)."""

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
