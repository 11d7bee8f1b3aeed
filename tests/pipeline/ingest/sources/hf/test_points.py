"""LiDAR scans from a Hugging Face store: one chunk at a time, the bag reader's points."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.hf.points import ScanReader, iter_hf_sweeps
from pipeline.ingest.sources.hf.store import HfStore, seconds_to_ns
from pipeline.ingest.sources.sweep_reader import iter_sweeps
from pipeline.synth.hf_layout import stamp_seconds
from schemas.recording_index import SWEEPS, read_index_table, table_path
from tests.pipeline.ingest.sources.hf.kit import INGEST, mission


class _Spy:
    """Wraps a zarr array; records the row span of every read."""

    def __init__(self, arr: Any) -> None:
        self.arr, self.spans = arr, []
        self.shape, self.chunks = arr.shape, arr.chunks

    def __getitem__(self, key: Any) -> Any:
        rows = key[0] if isinstance(key, tuple) else key
        self.spans.append(rows.stop - rows.start)
        return self.arr[key]


def test_points_are_read_one_chunk_at_a_time(tmp_path_factory: pytest.TempPathFactory) -> None:
    store = HfStore.open(mission(tmp_path_factory, "clean", "hf-zarr"))
    reader = ScanReader(store, "hesai_points_undistorted")
    spy = _Spy(reader.points)
    reader.points = spy  # type: ignore[assignment]
    scans = list(reader.rows())
    assert len(scans) == reader.n > reader.step  # more than one chunk
    assert max(spy.spans) <= reader.step  # never more than one chunk of scans
    assert len(spy.spans) == -(-reader.n // reader.step)  # each chunk read once


def test_hf_sweeps_equal_bag_sweeps(tmp_path_factory: pytest.TempPathFactory,
                                    tmp_path: Path) -> None:
    loaded = {}
    for fmt in ("rosbag", "hf-zarr"):
        rec = mission(tmp_path_factory, "faulty", fmt)  # with NaN points and an empty sweep
        res = ingest_recording(rec, tmp_path / fmt, INGEST)
        rows = read_index_table(table_path(res.index_dir, "sweeps"), SWEEPS).to_pylist()
        loaded[fmt] = list(iter_sweeps(rec, rows))
    assert len(loaded["rosbag"]) == len(loaded["hf-zarr"]) > 5
    for a, b in zip(loaded["rosbag"], loaded["hf-zarr"], strict=True):
        np.testing.assert_array_equal(a.xyz, b.xyz)
        np.testing.assert_array_equal(a.intensity, b.intensity)
        assert a.counts == b.counts
        assert (b.t_ns == b.t_ns[0]).all()  # no per-point time in the release


def test_index_row_must_match_the_store(tmp_path_factory: pytest.TempPathFactory) -> None:
    rec = mission(tmp_path_factory, "clean", "hf-zarr")
    row = {"topic": "hesai_points_undistorted", "ordinal": 3, "stamp_ns": 5}
    with pytest.raises(LookupError, match="timestamp row 3: stamp"):
        next(iter_hf_sweeps(rec, [row]))


@settings(max_examples=300, deadline=None)
@given(ns=st.one_of(st.integers(0, 8_990_000_000_000_000_000),
                    st.sampled_from([0, 1, 999_999_999, 1_717_000_000_123_456_789,
                                     8_990_000_000_000_000_000])))  # fmt: skip
def test_seconds_round_trip_within_float64_resolution(ns: int) -> None:
    """int64 ns -> float64 s (writer) -> int64 ns (reader): off by at most half a float64
    spacing at that time (0.12 us near 1.7e9 s) plus one ns of rounding, never more."""
    sec = stamp_seconds(ns)
    got, ok = seconds_to_ns(np.array([sec]))
    assert ok.all()
    assert abs(int(got[0]) - ns) <= np.spacing(sec) / 2 * 1e9 + 1


def test_unusable_seconds_are_flagged() -> None:
    _, ok = seconds_to_ns(np.array([np.nan, np.inf, -np.inf, 1e10, 1.7e9]))
    assert ok.tolist() == [False, False, False, False, True]
