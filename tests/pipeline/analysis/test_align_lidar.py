"""The LiDAR half of `m3gd align --consistency`: sensor poses read off the recorded odometry
(a cubic track) through each sensor's mounting, and a camera clock offset already declared in
`select.time_offset_s` read on the odometry's clock (slow: the whole check on a recording)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from scipy.spatial.transform import Rotation

from packets.reprojection_consistency import CubicTrack
from pipeline.analysis.align_lidar import BodyTrack, body_track
from schemas.errors import DataError
from schemas.recording_index import ODOMETRY, table_path, write_index_table
from tests.pipeline.analysis.test_align_consistency import consistency_of, rotation_error_deg

NS = 1_000_000_000


def test_body_track_composes_the_sensor_mounting_and_names_an_unknown_sensor(
        tmp_path: Path) -> None:
    """The body turns about z at 1 rad/s while moving along x; a mount turned and shifted:
    the sensor's pose is the body's (cubic, exact on this motion's samples and near it between
    them) times the mount, not the mount times the body."""
    t = np.arange(8) * 0.1
    body = np.tile(np.eye(4), (8, 1, 1))
    body[:, :3, :3] = Rotation.from_rotvec(np.outer(t, [0.0, 0.0, 1.0])).as_matrix()
    body[:, 0, 3] = 0.5 * t
    mount = np.eye(4)
    mount[:3, :3] = Rotation.from_rotvec([0.3, 0.0, 0.0]).as_matrix()
    mount[:3, 3] = [0.1, 0.2, 0.3]
    track = BodyTrack(CubicTrack((t * NS).round().astype(np.int64), body), {"front": mount},
                      tmp_path / "calibration.parquet")
    at = track.sensor_at("front", 0.35 * NS)
    want = np.eye(4)
    want[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.35]).as_matrix()
    want[0, 3] = 0.175
    assert at is not None and np.allclose(at, want @ mount, atol=1e-6)
    assert not np.allclose(at, mount @ want, atol=1e-3)
    assert track.sensor_at("front", 0.8 * NS) is None  # after the odometry
    with pytest.raises(DataError, match=r"calibration\.parquet: no row of sensor 'left'"):
        track.sensor_at("left", 0.35 * NS)


@pytest.mark.slow
def test_a_declared_clock_offset_leaves_nothing_to_recover(tmp_path: Path) -> None:
    """The camera's clock runs 30 ms ahead and `select.time_offset_s` says so: the check finds
    no further offset and still the mounting rotation."""
    rot = (0.0, 0.5, -0.3)
    (row,) = consistency_of(tmp_path, 0.03, rot, declared_offset_s=0.03)[1].table.to_pylist()
    assert abs(row["offset_ms"]) < 5.0, row
    assert rotation_error_deg(row, rot) < 0.2, row


def test_an_odometry_of_one_sample_is_refused_naming_the_table(tmp_path: Path) -> None:
    idx = tmp_path / "index" / "m"
    idx.mkdir(parents=True)
    write_index_table(pa.table({"stamp_ns": pa.array([5], pa.int64()),
                                "frame_id": ["odom"], "child_frame_id": ["base"],
                                "position": pa.array([[0.0, 0.0, 0.0]], ODOMETRY.field(
                                    "position").type),
                                "quat_xyzw": pa.array([[0.0, 0.0, 0.0, 1.0]], ODOMETRY.field(
                                    "quat_xyzw").type)}, schema=ODOMETRY), ODOMETRY,
                      table_path(idx, "odometry"))
    with pytest.raises(DataError, match=r"odometry\.parquet: 1 odometry sample"):
        body_track(idx)
