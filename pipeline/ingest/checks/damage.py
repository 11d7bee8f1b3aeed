"""Damaged regions of a bag and the per-bag message accounting.

A damaged region is a byte range of a bag whose messages could not be read (a chunk that does
not decompress, a record whose header is garbage, a cut end of file). It carries what it could
have held: the topics and the log-time range, and the message count when the bag's chunk index
knows it (-1 when only a forward scan found the region). Every region becomes one row of the
damage table and one `damaged_region` reject, so nothing is lost without a word.
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.ingest.checks.rejects import Reject
from schemas.recording_index import Reason

UNKNOWN = -1
"""Message count of a region found by a forward scan (no chunk index to say how many)."""


@dataclass(frozen=True)
class DamagedRegion:
    """Bytes [byte_start, byte_end) of `file` that could not be read.

    topics: topics it could have held (empty: unknown); first_ns / last_ns: log-time range of
    the messages it could have held (int64 ns; the neighbouring readable stamps when unknown);
    messages: how many messages of the streamed topics it held per the index, or UNKNOWN.
    """

    file: str
    byte_start: int
    byte_end: int
    topics: tuple[str, ...]
    first_ns: int
    last_ns: int
    messages: int
    cause: str

    def describe(self) -> str:
        """One line: byte range, what it could have held, why it is unreadable."""
        what = ", ".join(self.topics) if self.topics else "unknown topics"
        count = "an unknown number of" if self.messages == UNKNOWN else str(self.messages)
        return (f"bytes {self.byte_start}-{self.byte_end} unreadable ({self.cause}); could have "
                f"held {count} message(s) of {what} with log times {self.first_ns}.."
                f"{self.last_ns} ns")

    def reject(self) -> Reject:
        """The reject row telling the user about this region."""
        return Reject(self.file, ",".join(self.topics), self.first_ns, Reason.DAMAGED_REGION,
                      self.describe())

    def row(self) -> dict[str, object]:
        """The damage-table row."""
        return {"file": self.file, "byte_start": self.byte_start, "byte_end": self.byte_end,
                "topics": list(self.topics), "first_ns": self.first_ns, "last_ns": self.last_ns,
                "messages": self.messages, "cause": self.cause}  # fmt: skip
