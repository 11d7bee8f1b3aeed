"""Reading a synthetic mission back: bag messages, clouds, calibration and ground-truth poses."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
from rosbags.highlevel import AnyReader

from pipeline.synth.rosio import ros1_typestore

FIELD_DTYPES = {7: "<f4", 4: "<u2", 8: "<f8"}


def stamp_ns(header: Any) -> int:
    """Header stamp as int64 ns."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def read_topic(bag: Path, topic: str) -> list[tuple[int, Any]]:
    """(bag time ns, message) of every message on `topic` in one bag, in bag-time order."""
    with AnyReader([bag], default_typestore=ros1_typestore()) as r:
        conns = [c for c in r.connections if c.topic == topic]
        return [(t, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages(conns)]


def cloud_points(msg: Any) -> np.ndarray:
    """Structured points of a PointCloud2, dtype built from msg.fields (offsets not assumed)."""
    dt = np.dtype(
        {
            "names": [f.name for f in msg.fields],
            "formats": [FIELD_DTYPES[f.datatype] for f in msg.fields],
            "offsets": [f.offset for f in msg.fields],
            "itemsize": msg.point_step,
        }
    )
    return np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), dtype=dt)


def calibration(gt_dir: Path) -> dict[str, Any]:
    """calibration.json."""
    return json.loads((gt_dir / "calibration.json").read_text())


def table(gt_dir: Path, name: str) -> dict[str, list[Any]]:
    """A ground-truth Parquet table as a column dict."""
    return pq.read_table(gt_dir / f"{name}.parquet").to_pydict()
