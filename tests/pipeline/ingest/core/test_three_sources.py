"""The same faults through three sources (ROS 1 bags, the HF Zarr layout, KITTI-360) give the
same rejects: one ingest core (`core.gated_pass`, which the bag stream feeds too) runs the
stamp gate, the point rules and the plausibility checks for all of them."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr

from pipeline.ingest.index.ingest_result import IngestResult
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.kitti360 import Kitti360Source
from schemas.recording_index import REJECTS, SWEEPS, read_index_table, table_path
from tests.pipeline.ingest.sources import kitti360_kit as k360
from tests.pipeline.ingest.sources.hf import kit as hf

FAULTS = ("duplicate_stamp", "out_of_order_stamp", "stream_gap", "empty_sweep")
"""The reasons of the faulty recording's stamp, gap and NaN faults (a sweep of NaN points only
is empty; NaN points among valid ones are dropped and counted, the sweep kept)."""


def _rejects(res: IngestResult) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = read_index_table(table_path(res.index_dir, "rejects"),
                                                  REJECTS).to_pylist()  # fmt: skip
    return rows


def _sensor_counts(res: IngestResult) -> Counter[str]:
    """Reject counts by reason of the sensor streams (KITTI-360's poses.txt, which takes
    image_00's stamps, repeats that camera's stamp rejects: left out)."""
    return Counter(r["reason"] for r in _rejects(res) if r["topic"] != "poses")


@pytest.fixture(scope="module")
def faulty(tmp_path_factory: pytest.TempPathFactory) -> dict[str, IngestResult]:
    out = tmp_path_factory.mktemp("three")
    return {
        "rosbag": ingest_recording(k360.bags_of(tmp_path_factory, "faulty"), out / "b",
                                   hf.INGEST),
        "hf-zarr": ingest_recording(hf.mission(tmp_path_factory, "faulty", "hf-zarr"),
                                    out / "h", hf.INGEST),
        "kitti360": Kitti360Source().ingest(k360.kitti_root(tmp_path_factory, "faulty"),
                                            out / "k", k360.INGEST, None, "faulty"),
    }  # fmt: skip


def test_duplicate_stamp_nan_points_and_gaps_are_the_same_rejects(
        faulty: dict[str, IngestResult]) -> None:  # fmt: skip
    counts = {f: {r: _sensor_counts(res)[r] for r in FAULTS} for f, res in faulty.items()}
    assert counts["rosbag"] == counts["hf-zarr"] == counts["kitti360"]
    assert all(n >= 1 for n in counts["rosbag"].values()), counts
    kept = [sum(1 for r in read_index_table(table_path(res.index_dir, "sweeps"), SWEEPS)
                .to_pylist() if r["n_nan"] > 0) for res in faulty.values()]  # fmt: skip
    assert kept[0] == kept[1] == kept[2] >= 1  # NaN returns dropped, their sweeps kept


def test_every_source_runs_the_sweep_and_pose_checks(faulty: dict[str, IngestResult]) -> None:
    for f, res in faulty.items():
        checks = {r["check"] for r in res.checks}
        assert {"point_limits", "pose_jump"} <= checks, f


def _far_point_hf(rec: Path) -> None:
    arr = zarr.open_array(str(rec / "data" / "hesai_points_undistorted" / "points"), mode="r+")
    row = arr[15]
    row[0] = [900.0, 0.0, 0.0]  # beyond checks.max_range_m (500 m), a finite point
    arr[15] = row


def _far_point_k360(root: Path) -> None:
    path = sorted((root / "data_3d_raw").rglob("velodyne_points/data/*.bin"))[15]
    pts = np.fromfile(path, np.float32).reshape(-1, 4)
    pts[0, :3] = [900.0, 0.0, 0.0]
    pts.tofile(path)


def test_an_implausible_point_is_bad_pointcloud_in_hf_and_kitti360(
        tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:  # fmt: skip
    """Was: kept (the HF and KITTI-360 readers ran no plausibility check). A point at 900 m in
    one sweep is rejected by `point_limits`, as the bag path rejects it."""
    rec = hf.copy_of(tmp_path_factory, "clean", tmp_path)
    _far_point_hf(rec)
    root = k360.copy_of(tmp_path_factory, tmp_path)
    _far_point_k360(root)
    res = [ingest_recording(rec, tmp_path / "h", hf.INGEST),
           Kitti360Source().ingest(root, tmp_path / "k", k360.INGEST, None, "clean")]
    for r in res:
        bad = [x for x in _rejects(r) if x["reason"] == "bad_pointcloud"]
        assert len(bad) == 1 and bad[0]["detail"].endswith("(point_limits): a damaged message")
        assert "900" in bad[0]["detail"]
