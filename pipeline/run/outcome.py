"""What a finished run produced per recording: a recording without any usable view is an error.

A run can finish every item and still produce nothing to train on (the LiDAR bag unreadable, no
odometry...). `empty_recordings` finds the recordings whose selection accepted no view and says
why in one line each: the selection's reject reasons and the ingest problems that dropped whole
bags, topics or cameras. The command exits non-zero for them unless `--allow-empty` is given.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pyarrow.compute as pc

from schemas.recording_index import (
    REJECTS,
    SELECTION,
    Reason,
    ViewStatus,
    index_dir,
    read_index_table,
    table_path,
)

NOTABLE_INGEST = frozenset({Reason.UNREADABLE_BAG, Reason.TRUNCATED_BAG, Reason.DAMAGED_REGION,
                            Reason.MISSING_TOPIC, Reason.MISSING_CAMERA_INFO,
                            Reason.BAD_CAMERA_INFO, Reason.MISSING_TF_EDGE})  # fmt: skip
"""Ingest reject reasons that explain a recording without usable views."""


def empty_reason(out_dir: Path, recording: str) -> str | None:
    """One line saying why `recording` has no usable view; None when it has one (or no selection).

    Counts are views of the selection by reject reason, then the ingest rejects that drop
    whole bags, topics or cameras.
    """
    idx = index_dir(out_dir, recording)
    path = table_path(idx, "selection")
    if not path.exists():
        return None
    sel = read_index_table(path, SELECTION)
    if pc.sum(pc.equal(sel["status"], ViewStatus.OK.value)).as_py():
        return None
    views = Counter(sel["reason"].to_pylist())
    why = ", ".join(f"{r} {n}" for r, n in sorted(views.items())) or "no image was ingested"
    line = f"recording {recording}: no usable view ({sel.num_rows} view(s): {why})"
    rejects = table_path(idx, "rejects")
    if rejects.exists():
        rows = read_index_table(rejects, REJECTS).to_pylist()
        notable = Counter(r["reason"] for r in rows if r["reason"] in NOTABLE_INGEST)
        if notable:
            parts = ", ".join(f"{r} {n}" for r, n in sorted(notable.items()))
            line += f"; ingest: {parts} (see {rejects})"
    return line


def empty_recordings(out_dir: Path, recordings: list[str]) -> list[str]:
    """One line per recording of the run that has a selection but no usable view."""
    return [line for rec in recordings if (line := empty_reason(out_dir, rec)) is not None]
