"""Select on a tiny mission: nearest sweep, exact Δτ, T_cam_lidar vs ground truth, rejects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.ingest.recording import ingest_recording
from pipeline.select.views import select_views
from schemas.config import IngestConfig, SelectConfig
from schemas.recording_index import SELECTION, read_index_table, table_path
from tests.pipeline.ingest.bagkit import (
    T0_NS,
    Mission,
    camera_stamps,
    gt_T_base,
    lidar_stamps,
    odom_pose,
    write_mission,
)

CFG = IngestConfig(cameras=["front"], out_height=28, out_width=42)


def _run(tmp_path: Path, m: Mission, sel: SelectConfig | None = None) -> tuple:
    mission = write_mission(tmp_path, m)
    res = ingest_recording(mission, tmp_path / "out", CFG)
    out = select_views(res.index_dir, sel or SelectConfig(), CFG)
    rows = read_index_table(table_path(res.index_dir, "selection"), SELECTION).to_pylist()
    return out, rows


def test_nearest_sweep_dtau_and_chain_match_ground_truth(tmp_path: Path) -> None:
    m = Mission(camera_offset_ns=37_000_001)
    out, rows = _run(tmp_path, m)
    assert out.views == out.accepted == 10 and out.sweeps_unselected == 0
    sweeps = lidar_stamps(m)
    for r, tau in zip(rows, camera_stamps(m), strict=True):
        gt = int(np.argmin([abs(s - tau) for s in sweeps]))
        assert r["sweep"] == gt and r["sweep_stamp_ns"] == sweeps[gt]
        assert r["dtau_s"] == (sweeps[gt] - tau) / 1e9
        T_ob_img, T_ob_swp = odom_pose((tau - T0_NS) / 1e9), odom_pose((sweeps[gt] - T0_NS) / 1e9)
        T_cam_base = np.linalg.inv(gt_T_base("hdr_front"))
        gt_chain = T_cam_base @ np.linalg.inv(T_ob_img) @ T_ob_swp @ gt_T_base("hesai_lidar")
        np.testing.assert_allclose(np.reshape(r["T_cam_lidar"], (4, 4)), gt_chain, atol=1e-6)
        np.testing.assert_allclose(np.reshape(r["T_world_cam"], (4, 4)),
                                   T_ob_img @ gt_T_base("hdr_front"), atol=1e-6)  # fmt: skip


def test_dtau_bound_odometry_gap_and_unselected_sweeps(tmp_path: Path) -> None:
    m = Mission(seconds=1.0, lidar_hz=5.0, camera_offset_ns=60_000_000, odom_gap_s=(0.3, 0.75))
    out, rows = _run(tmp_path, m, SelectConfig(max_abs_dt_s=0.05, max_odom_gap_s=0.2))
    reasons = [r["reason"] for r in rows]
    cams = camera_stamps(m)
    for r, tau in zip(rows, cams, strict=True):
        t = (tau - T0_NS) / 1e9
        if abs(r["dtau_s"]) > 0.05:
            assert r["reason"] == "dtau_exceeded" and r["status"] == "rejected"
        elif 0.3 < t < 0.75 or 0.3 < (r["sweep_stamp_ns"] - T0_NS) / 1e9 < 0.75:
            assert r["reason"] == "odom_gap"
            np.testing.assert_array_equal(np.reshape(r["T_cam_lidar"], (4, 4)), np.eye(4))
        else:
            assert r["status"] == "ok", (t, r)
    assert "odom_gap" in reasons and "dtau_exceeded" in reasons
    assert out.rejected == {k: reasons.count(k) for k in set(reasons) if k}
    assert out.sweeps_selected + out.sweeps_unselected == out.sweeps_total == 5
    assert out.sweeps_unselected >= 1


def test_unknown_selection_version_is_refused(tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    _, _ = _run(tmp_path, Mission(seconds=0.3))
    path = table_path(tmp_path / "out" / "index" / "m0", "selection")
    table = pq.read_table(path)
    meta = dict(table.schema.metadata)
    meta[b"m3gd_format_version"] = b"99"
    pq.write_table(table.replace_schema_metadata(meta), path)
    with pytest.raises(ValueError, match="format version 99 is not supported"):
        read_index_table(path, SELECTION)


def test_repeated_odometry_stamps_are_named_with_the_table_and_row(tmp_path: Path) -> None:
    """Was: 'pose stamps must be strictly increasing' with no file, row or stamp."""
    import pyarrow.parquet as pq

    from schemas.recording_index import ODOMETRY, write_index_table

    mission = write_mission(tmp_path, Mission())
    res = ingest_recording(mission, tmp_path / "out", CFG)
    path = table_path(res.index_dir, "odometry")
    table = pq.read_table(path)
    write_index_table(table.take([0, 1, 1, 2]), ODOMETRY, path)
    s1 = table.column("stamp_ns")[1].as_py()
    with pytest.raises(ValueError, match=r"odometry.parquet: odometry stamps must be strictly "
                       rf"increasing; row 2 \({s1} ns\) follows row 1 \({s1} ns\)"):
        select_views(res.index_dir, SelectConfig(), CFG)
