"""File output of `m3gd eval`: the summary JSON and the per-target Parquet beside it.

Scoring itself is `model.scoring` (one loop shared by every command and bench).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pyarrow as pa

from model.evaluate import BASELINES, REPROJ_CANDIDATES
from schemas.atomic_io import write_text_atomic
from schemas.tables import eval_targets_schema, write_table


def write_eval(summary: dict[str, Any], rows: list[dict[str, Any]], path: Path) -> Path:
    """Write `summary` to `path` (JSON) and `rows` (`model.scoring.target_rows`) to its
    .parquet sibling, typed by `schemas.tables.eval_targets_schema`; returns `path`."""
    schema = eval_targets_schema(BASELINES, REPROJ_CANDIDATES)
    write_table(pa.Table.from_pylist(rows, schema=schema), schema, path.with_suffix(".parquet"))
    write_text_atomic(path, json.dumps(summary, indent=1))
    return path
