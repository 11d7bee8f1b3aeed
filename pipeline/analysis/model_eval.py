"""File output of `m3gd eval`: the summary JSON and the per-target Parquet beside it.

Scoring itself is `model.scoring` (one loop shared by every command and bench).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from schemas.atomic_io import write_text_atomic


def write_eval(summary: dict[str, Any], rows: list[dict[str, Any]], path: Path) -> Path:
    """Write `summary` to `path` (JSON) and `rows` to its .parquet sibling; returns `path`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), path.with_suffix(".parquet"))
    write_text_atomic(path, json.dumps(summary, indent=1))
    return path
