"""A recording with no usable view is told in one line, with the ingest reasons that explain it."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa

from pipeline.run.outcome import NOTABLE_INGEST, empty_reason
from schemas.recording_index import (
    REJECTS,
    SELECTION,
    Reason,
    index_dir,
    table_path,
    write_index_table,
)


def _default(t: pa.DataType) -> object:
    if pa.types.is_string(t) or pa.types.is_large_string(t):
        return ""
    if pa.types.is_boolean(t):
        return False
    if pa.types.is_integer(t) or pa.types.is_floating(t):
        return 0
    if pa.types.is_list(t) or pa.types.is_fixed_size_list(t):
        return [_default(t.value_type)] * (t.list_size if pa.types.is_fixed_size_list(t) else 0)
    raise TypeError(t)


def _table(schema: pa.Schema, rows: list[dict]) -> pa.Table:
    cols = {f.name: [r.get(f.name, _default(f.type)) for r in rows] for f in schema}
    return pa.Table.from_pydict(cols, schema=schema)


def test_notable_ingest_reasons_are_reason_codes() -> None:
    assert set(Reason) >= NOTABLE_INGEST
    assert "truncated_bag" in NOTABLE_INGEST and "corrupt_jpeg" not in NOTABLE_INGEST


def test_empty_recording_line_names_selection_and_notable_ingest_reasons(tmp_path: Path) -> None:
    idx = index_dir(tmp_path, "rec")
    idx.mkdir(parents=True)
    sel = [{"status": "rejected", "reason": "no_sweep"}]
    write_index_table(_table(SELECTION, sel), SELECTION, table_path(idx, "selection"))
    rej = [{"reason": r} for r in
           ("truncated_bag", "corrupt_jpeg", "truncated_bag")]  # fmt: skip
    write_index_table(_table(REJECTS, rej), REJECTS, table_path(idx, "rejects"))
    line = empty_reason(tmp_path, "rec")
    assert line is not None
    assert line.startswith("recording rec: no usable view (1 view(s): no_sweep 1)")
    assert "ingest: truncated_bag 2" in line and "corrupt_jpeg" not in line
