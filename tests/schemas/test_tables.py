"""Parquet schemas: round trips, and refusal of unknown versions and kinds."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from schemas.tables import ALL_TABLES, CELL_STATS, VIEW_STATS, read_table, write_table
from schemas.versioning import VERSION_KEY, UnknownSchemaVersion


def _row_for(schema: pa.Schema) -> dict[str, list[object]]:
    samples: dict[str, object] = {
        "string": "x", "int64": 7, "int32": 3, "int16": 2, "double": 0.25, "bool": True,
        "list<item: int64>": [1, 2], "list<item: bool>": [True, False],
    }
    return {f.name: [samples[str(f.type)]] for f in schema}


@pytest.mark.parametrize("name", sorted(ALL_TABLES))
def test_round_trip(tmp_path: Path, name: str) -> None:
    schema = ALL_TABLES[name]
    table = pa.table(_row_for(schema))
    path = tmp_path / f"{name}.parquet"
    write_table(table, schema, path)
    back = read_table(path, schema)
    assert back.schema.equals(schema, check_metadata=False)
    assert back.to_pylist() == table.cast(schema).to_pylist()


def test_unknown_version_refused(tmp_path: Path) -> None:
    table = pa.table(_row_for(VIEW_STATS)).cast(VIEW_STATS)
    meta = dict(VIEW_STATS.metadata)
    meta[VERSION_KEY.encode()] = b"42"
    path = tmp_path / "future.parquet"
    pq.write_table(table.replace_schema_metadata(meta), path)
    with pytest.raises(UnknownSchemaVersion, match=r"future\.parquet.*42"):
        read_table(path, VIEW_STATS)


def test_wrong_kind_refused(tmp_path: Path) -> None:
    path = tmp_path / "v.parquet"
    write_table(pa.table(_row_for(VIEW_STATS)), VIEW_STATS, path)
    with pytest.raises(ValueError, match="cell_stats"):
        read_table(path, CELL_STATS)
