"""ROS2 (MCAP) recordings ingest the same as ROS1: same index, same sweeps back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.convert.converter import convert
from rosbags.typesys import Stores, get_typestore

from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.sweep_reader import load_sweep
from schemas.config import IngestConfig
from schemas.recording_index import IMAGES, SWEEPS, read_index_table, table_path
from tests.pipeline.ingest.bagkit import Mission, write_mission

CFG = IngestConfig(cameras=["front"], out_height=28, out_width=42)


def test_mcap_mission_matches_ros1(tmp_path: Path) -> None:
    src = write_mission(tmp_path / "ros1", Mission(seconds=0.5))
    dst = tmp_path / "ros2" / "m0"
    dst.mkdir(parents=True)
    humble = get_typestore(Stores.ROS2_HUMBLE)
    convert(sorted(src.glob("*.bag")), dst / "all", "mcap", 9, None, "file", None, humble,
            [], [], [], [])  # fmt: skip
    a = ingest_recording(src, tmp_path / "out1", CFG)
    b = ingest_recording(dst, tmp_path / "out2", CFG)
    assert a.images == b.images == {"front": 5} and a.sweeps == b.sweeps == 5
    for name, schema in (("images", IMAGES), ("sweeps", SWEEPS)):
        ta = read_index_table(table_path(a.index_dir, name), schema)
        tb = read_index_table(table_path(b.index_dir, name), schema)
        assert ta.column("stamp_ns").to_pylist() == tb.column("stamp_ns").to_pylist()
    row_b = read_index_table(table_path(b.index_dir, "sweeps"), SWEEPS).to_pylist()[2]
    row_a = read_index_table(table_path(a.index_dir, "sweeps"), SWEEPS).to_pylist()[2]
    assert row_b["file"] == "all"
    np.testing.assert_array_equal(load_sweep(dst, row_b).xyz, load_sweep(src, row_a).xyz)
