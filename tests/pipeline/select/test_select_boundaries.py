"""Select's boundaries: the clock offset's sign and exact nanoseconds, |Δτ| equal to the bound
(accepted: only exceeding rejects), a recording without any sweep (every view rejected), an
odometry gap at the image alone, and a camera without images."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pipeline.ingest.recording import ingest_recording
from pipeline.select.views import load_odometry, select_views
from schemas.config import IngestConfig, SelectConfig
from schemas.recording_index import (
    CALIBRATION,
    ODOMETRY,
    SELECTION,
    SWEEPS,
    read_index_table,
    table_path,
)
from schemas.recording_index import write_index_table as write_table
from tests.pipeline.ingest.bagkit import Mission, write_mission

CFG = IngestConfig(cameras=["front"], out_height=28, out_width=42)


@pytest.fixture(scope="module")
def index(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The index of a tiny mission (1 s, camera and LiDAR at 10 Hz, 13 ms apart)."""
    tmp = tmp_path_factory.mktemp("select")
    return ingest_recording(write_mission(tmp, Mission()), tmp / "out", CFG).index_dir


def _select(index: Path, tmp_path: Path, **cfg: Any) -> tuple[Any, list[dict[str, Any]]]:
    """Select on a copy of `index`; (result, selection rows)."""
    idx = tmp_path / "idx"
    shutil.copytree(index, idx)
    out = select_views(idx, SelectConfig(**cfg), CFG)
    return out, read_index_table(table_path(idx, "selection"), SELECTION).to_pylist()


def _stamps(index: Path, name: str) -> np.ndarray:
    schema = {"sweeps": SWEEPS, "odometry": ODOMETRY}.get(name)
    table = read_index_table(table_path(index, name), schema) if schema else None
    if table is None:
        import pyarrow.parquet as pq

        table = pq.read_table(table_path(index, name))
    return table.column("stamp_ns").to_numpy().astype(np.int64)


@pytest.mark.parametrize("offset_ns", [999_999_999, -37_000_003])
def test_clock_offset_is_subtracted_from_the_image_stamp_to_the_nanosecond(
        index: Path, tmp_path: Path, offset_ns: int) -> None:
    _, rows = _select(index, tmp_path, time_offset_s=offset_ns / 1e9, max_abs_dt_s=10.0)
    sweeps = _stamps(index, "sweeps")
    for r in rows:
        tau = r["stamp_ns"] - offset_ns  # the image on the LiDAR clock; the row keeps its stamp
        want = int(np.argmin(np.abs(sweeps - tau)))
        assert r["sweep"] == want and r["sweep_stamp_ns"] == sweeps[want]
        assert r["dtau_s"] == (sweeps[want] - tau) / 1e9  # exact: integer ns, one division
    assert sorted(r["stamp_ns"] for r in rows) == sorted(_stamps(index, "images").tolist())


def test_dtau_equal_to_the_bound_is_accepted_only_beyond_it_rejected(
        index: Path, tmp_path: Path) -> None:
    _, rows = _select(index, tmp_path)
    bound = abs(rows[3]["dtau_s"])  # 13 ms: every view of this mission has the same |Δτ|
    assert bound > 0 and {abs(r["dtau_s"]) for r in rows} == {bound}
    _, at = _select(index, tmp_path / "at", max_abs_dt_s=bound)
    assert {r["status"] for r in at} == {"ok"}
    _, below = _select(index, tmp_path / "below", max_abs_dt_s=np.nextafter(bound, 0.0))
    assert {r["reason"] for r in below} == {"dtau_exceeded"}


def test_no_sweep_at_all_rejects_every_view_and_points_at_no_sweep(
        index: Path, tmp_path: Path) -> None:
    idx = tmp_path / "idx"
    shutil.copytree(index, idx)
    path = table_path(idx, "sweeps")
    write_table(read_index_table(path, SWEEPS).slice(0, 0), SWEEPS, path)
    out = select_views(idx, SelectConfig(), CFG)
    rows = read_index_table(table_path(idx, "selection"), SELECTION).to_pylist()
    assert rows and out.views == len(rows) and out.accepted == 0
    assert out.rejected == {"no_sweep": len(rows)}
    assert (out.sweeps_total, out.sweeps_selected, out.sweeps_unselected) == (0, 0, 0)
    for r in rows:
        assert r["status"] == "rejected" and r["reason"] == "no_sweep"
        assert r["sweep"] == -1 and r["sweep_stamp_ns"] == -1 and r["dtau_s"] == 0.0
        np.testing.assert_array_equal(np.reshape(r["T_cam_lidar"], (4, 4)), np.eye(4))


def test_odometry_gap_at_the_image_alone_rejects_the_view(tmp_path: Path) -> None:
    """Odometry at 0.30 s and 0.40 s only (the 0.35 s sample missing); the image at 0.313 s
    falls in that 0.1 s gap, its sweep at 0.30 s does not: the view is an odometry gap, its
    poses identity, while every other view is accepted."""
    m = Mission(odom_gap_s=(0.301, 0.399))
    idx = ingest_recording(write_mission(tmp_path, m), tmp_path / "out", CFG).index_dir
    select_views(idx, SelectConfig(max_odom_gap_s=0.06), CFG)
    rows = read_index_table(table_path(idx, "selection"), SELECTION).to_pylist()
    assert [r["reason"] for r in rows] == [""] * 3 + ["odom_gap"] + [""] * 6
    for key in ("T_cam_lidar", "T_world_cam"):
        np.testing.assert_array_equal(np.reshape(rows[3][key], (4, 4)), np.eye(4))


def test_a_camera_without_images_adds_no_row_and_keeps_the_others(
        index: Path, tmp_path: Path) -> None:
    import pyarrow as pa

    idx = tmp_path / "idx"
    shutil.copytree(index, idx)
    path = table_path(idx, "calibration")
    calib = read_index_table(path, CALIBRATION)
    rows = calib.to_pylist()
    left = {**next(r for r in rows if r["sensor"] == "front"), "sensor": "left"}
    write_table(pa.Table.from_pylist([*rows, left], schema=calib.schema), CALIBRATION, path)
    cfg = IngestConfig(cameras=["front", "left"], out_height=28, out_width=42)
    out = select_views(idx, SelectConfig(), cfg)  # 'left' calibrated, without any image
    got = read_index_table(table_path(idx, "selection"), SELECTION).to_pylist()
    assert {r["camera"] for r in got} == {"front"} and out.views == out.accepted == 10


def _with_stamps(index: Path, tmp_path: Path, table: str, stamps: list[int]) -> Path:
    """A copy of `index` whose `table` (sweeps or odometry) is its first len(stamps) rows with
    these stamps."""
    import pyarrow as pa

    schema = {"sweeps": SWEEPS, "odometry": ODOMETRY}[table]
    idx = tmp_path / "idx"
    shutil.copytree(index, idx)
    path = table_path(idx, table)
    rows = read_index_table(path, schema).slice(0, len(stamps))
    col = rows.schema.get_field_index("stamp_ns")
    rows = rows.set_column(col, rows.schema.field(col), pa.array(stamps, pa.int64()))
    write_table(rows, schema, path)
    return idx


def test_sweep_stamps_must_increase_by_at_least_one_nanosecond(
        index: Path, tmp_path: Path) -> None:
    t0 = int(_stamps(index, "sweeps")[0])
    ok = _with_stamps(index, tmp_path / "ok", "sweeps", [t0, t0 + 1])  # 1 ns apart: increasing
    assert select_views(ok, SelectConfig(), CFG).sweeps_total == 2
    for name, stamps in (("same", [t0, t0]), ("back", [t0, t0 - 1])):
        idx = _with_stamps(index, tmp_path / name, "sweeps", stamps)
        with pytest.raises(ValueError, match=rf"^{table_path(idx, 'sweeps')}: sweep stamps of "
                           "LiDAR 'lidar' are not increasing$"):
            select_views(idx, SelectConfig(), CFG)


def test_no_calibrated_camera_gives_an_empty_selection(index: Path, tmp_path: Path) -> None:
    idx = tmp_path / "idx"
    shutil.copytree(index, idx)
    cfg = IngestConfig(cameras=["left"], out_height=28, out_width=42)  # 'front' only calibrated
    out = select_views(idx, SelectConfig(), cfg)
    assert out.index_dir == idx and (out.views, out.accepted, out.rejected) == (0, 0, {})
    assert read_index_table(table_path(idx, "selection"), SELECTION).num_rows == 0


def test_odometry_stamps_one_nanosecond_apart_are_increasing(
        index: Path, tmp_path: Path) -> None:
    t = _stamps(index, "odometry")
    stamps = [int(t[0]), int(t[0]) + 1, *(int(s) for s in t[2:])]
    idx = _with_stamps(index, tmp_path, "odometry", stamps)
    np.testing.assert_array_equal(load_odometry(idx).stamps, stamps)
    assert select_views(idx, SelectConfig(), CFG).views == 10


@pytest.mark.parametrize(("extra_ns", "accepted"), [(0, 10), (1, 0)])
def test_odometry_gap_bound_is_exact_to_the_nanosecond_at_two_seconds(
        index: Path, tmp_path: Path, extra_ns: int, accepted: int) -> None:
    """Two odometry samples 2 s (+ extra_ns) apart around the whole 1 s recording and
    max_odom_gap_s = 2: a gap of exactly 2e9 ns interpolates every view, one more ns none."""
    t0 = int(min(_stamps(index, "images")[0], _stamps(index, "sweeps")[0])) - 500_000_000
    idx = _with_stamps(index, tmp_path, "odometry", [t0, t0 + 2_000_000_000 + extra_ns])
    out = select_views(idx, SelectConfig(max_odom_gap_s=2.0), CFG)
    assert out.views == 10 and out.accepted == accepted
    if not accepted:
        assert out.rejected == {"odom_gap": 10}
