"""Reading a `.rrd` back with the Rerun SDK's own reader (tests only)."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader

Rows = dict[str, list[tuple[int | None, dict[str, Any]]]]


def read_rrd(path: Path) -> Rows:
    """entity path -> rows (stamp ns or None when static, component name -> Arrow value),
    sorted by stamp; one row per logged archetype call of every chunk of the file."""
    rows: Rows = defaultdict(list)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if ":" in n]
        stamps = (batch["stamp"].cast(pa.int64()).to_pylist() if "stamp" in batch.schema.names
                  else [None] * batch.num_rows)
        for i in range(batch.num_rows):
            row = {n: batch[n][i] for n in names if batch[n][i].is_valid}
            rows[chunk.entity_path].append((stamps[i], row))
    for entity in rows:
        rows[entity].sort(key=lambda r: -1 if r[0] is None else r[0])
    return dict(rows)


def with_component(rows: Rows, entity: str, component: str) -> list[tuple[int | None, Any]]:
    """(stamp, value) of the rows of `entity` holding `component`."""
    return [(t, r[component]) for t, r in rows.get(entity, []) if component in r]


def points(value: Any, dim: int) -> np.ndarray:
    """A list-of-fixed-size-list Arrow value as an (N, dim) float64 array."""
    return np.asarray(value.values.flatten().to_numpy(), np.float64).reshape(-1, dim)


CHANNEL_DTYPES = {6: np.uint8, 34: np.float32}
"""Rerun ChannelDatatype codes of the images m3gd logs (U8, F32)."""
CHANNELS = {None: 1, 1: 1, 2: 3}
"""Rerun ColorModel codes (none for depth, L, RGB) -> channels."""


def image(row: dict[str, Any], archetype: str = "Image") -> np.ndarray:
    """The (H, W[, C]) array of a logged raw image row (Image or DepthImage)."""
    fmt = row[f"{archetype}:format"][0].as_py()
    raw = bytes(row[f"{archetype}:buffer"][0].values.to_numpy())
    arr = np.frombuffer(raw, CHANNEL_DTYPES[fmt["channel_datatype"]])
    channels = CHANNELS[fmt["color_model"]]
    shape = (fmt["height"], fmt["width"]) + ((channels,) if channels > 1 else ())
    return arr.reshape(shape)
