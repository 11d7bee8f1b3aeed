"""Bad input in a Hugging Face mission: named with file, array and row; good rows around kept."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr

from pipeline.ingest.index.ingest_result import IngestResult
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.hf.store import seconds_to_ns
from schemas.config import HfConfig, TopicsConfig
from schemas.errors import DataError
from schemas.recording_index import (
    ACCOUNTING,
    DAMAGE,
    IMAGES,
    INDEX_TABLES,
    ODOMETRY,
    REJECTS,
    SWEEPS,
    read_index_table,
    table_path,
)
from tests.pipeline.ingest.sources.hf.kit import INGEST, copy_of, mission

LIDAR = "hesai_points_undistorted"


@pytest.fixture
def rec(tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> Path:
    return copy_of(tmp_path_factory, "clean", tmp_path)


def _ingest(rec: Path, **cfg: Any) -> tuple[IngestResult, list[dict[str, Any]]]:
    res = ingest_recording(rec, rec.parent / "out", INGEST.model_copy(update=cfg))
    return res, read_index_table(table_path(res.index_dir, "rejects"), REJECTS).to_pylist()


def _array(rec: Path, path: str) -> zarr.Array:
    arr = zarr.open_array(str(rec / "data" / path), mode="r+")
    assert isinstance(arr, zarr.Array)
    return arr


def _clean(factory: pytest.TempPathFactory, name: str, schema: Any) -> int:
    res = ingest_recording(mission(factory, "clean", "hf-zarr"), factory.mktemp("c"), INGEST)
    return read_index_table(table_path(res.index_dir, name), schema).num_rows


def test_missing_jpeg_is_a_reject_naming_file_and_row(rec: Path) -> None:
    (rec / "images" / "hdr_front" / "000007.jpeg").unlink()
    res, rejects = _ingest(rec)
    assert res.rejects == {"missing_file": 1}
    (r,) = rejects
    assert r["file"] == "images/hdr_front/000007.jpeg" and r["topic"] == "hdr_front"
    assert "row 7 of data/hdr_front/timestamp" in r["detail"]
    rows = read_index_table(table_path(res.index_dir, "images"), IMAGES).to_pylist()
    front = [x["ordinal"] for x in rows if x["camera"] == "front"]
    assert 6 in front and 8 in front and 7 not in front  # neighbours kept
    assert res.images["front"] == res.images["left"] - 1


def test_valid_beyond_maxp_is_a_reject_naming_array_and_row(
        rec: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    valid = _array(rec, f"{LIDAR}/valid")
    max_p = _array(rec, f"{LIDAR}/points").shape[1]
    valid[5, 0] = max_p + 1
    res, rejects = _ingest(rec)
    assert res.rejects == {"bad_pointcloud": 1}
    assert rejects[0]["file"] == f"data/{LIDAR}/valid"
    detail = rejects[0]["detail"]
    assert f"data/{LIDAR}/valid row 5: valid = {max_p + 1} is outside 0..maxP" in detail
    sweeps = read_index_table(table_path(res.index_dir, "sweeps"), SWEEPS).to_pylist()
    assert [s["ordinal"] for s in sweeps if 3 <= s["ordinal"] <= 7] == [3, 4, 6, 7]
    assert len(sweeps) == _clean(tmp_path_factory, "sweeps", SWEEPS) - 1


def test_damaged_chunk_rejects_its_rows_only(rec: Path) -> None:
    chunk = rec / "data" / LIDAR / "points" / "1.0.0"  # scans 16..31 (chunks of 16 scans)
    chunk.write_bytes(b"not blosc")
    res, rejects = _ingest(rec)
    n = _array(rec, f"{LIDAR}/timestamp").shape[0]
    assert res.rejects == {"bad_pointcloud": n - 16, "damaged_region": 1} and res.sweeps == 16
    rows = [r for r in rejects if r["reason"] == "bad_pointcloud"]
    assert rows[0]["file"] == f"data/{LIDAR}/points"
    assert f"rows 16..{n - 1} (one chunk) cannot be read: DataError" in rows[0]["detail"]
    assert "1.0.0: 9 bytes, shorter than the 16-byte blosc header" in rows[0]["detail"]
    # was: no damage row for an HF recording; now one per unreadable chunk, with its stamps
    (region,) = read_index_table(table_path(res.index_dir, "damage"), DAMAGE).to_pylist()
    stamps, _ = seconds_to_ns(np.asarray(_array(rec, f"{LIDAR}/timestamp")[:], np.float64))
    assert region["file"] == f"data/{LIDAR}/points" and region["topics"] == [LIDAR]
    assert region["messages"] == n - 16 and region["first_ns"] == stamps[16]
    assert region["last_ns"] == stamps[n - 1]
    assert any(w.startswith(f"data/{LIDAR}/points") for w in res.warnings)


def test_nan_pose_is_a_reject_naming_array_and_row(rec: Path) -> None:
    """A NaN pose is `bad_pose`, as in a bag (was `undecodable_message` before the ingest core
    ran every source's rejects)."""
    pos = _array(rec, "anymal_state_odometry/pose_pos")
    pos[11] = [np.nan, 0.0, 0.0]
    res, rejects = _ingest(rec)
    assert res.rejects == {"bad_pose": 1}
    detail = rejects[0]["detail"]
    assert "data/anymal_state_odometry/pose_pos, pose_orien row 11: non-finite" in detail
    odo = read_index_table(table_path(res.index_dir, "odometry"), ODOMETRY)
    assert odo.num_rows == pos.shape[0] - 1


def test_accounting_rows_per_group(rec: Path) -> None:
    """Was: an HF recording wrote no accounting table. One row per group: rows read = kept
    (index rows) + rejected (reject rows, whatever file they name)."""
    (rec / "images" / "hdr_front" / "000007.jpeg").unlink()
    _array(rec, "anymal_state_odometry/pose_pos")[11] = [np.nan, 0.0, 0.0]
    res, rejects = _ingest(rec)
    acc = {a["topic"]: a for a in read_index_table(table_path(res.index_dir, "accounting"),
                                                   ACCOUNTING).to_pylist()}  # fmt: skip
    assert {"hdr_front", LIDAR, "anymal_state_odometry"} <= set(acc)
    for group, a in acc.items():
        assert a["file"] == f"data/{group}" and a["read"] == a["kept"] + a["rejected"], a
        assert a["rejected"] == sum(r["topic"] == group for r in rejects)
    assert acc["hdr_front"]["rejected"] == 1 and acc["anymal_state_odometry"]["rejected"] == 1
    assert acc["hdr_front"]["kept"] == res.images["front"]
    assert acc[LIDAR]["kept"] == res.sweeps and acc["anymal_state_odometry"]["kept"] == res.odometry


def test_unsorted_and_duplicate_timestamps(rec: Path) -> None:
    ts = _array(rec, "hdr_front/timestamp")
    t = ts[:]
    t[4], t[5] = t[5], t[4]  # two rows swapped: neither stamp can be trusted
    t[12] = t[11]  # a duplicate: the first copy is kept
    ts[:] = t
    res, rejects = _ingest(rec)
    assert res.rejects == {"out_of_order_stamp": 2, "duplicate_stamp": 1}
    details = sorted(r["detail"] for r in rejects)
    assert any(d.startswith("data/hdr_front/timestamp row 4:") for d in details)
    assert any(d.startswith("data/hdr_front/timestamp row 5:") for d in details)
    assert any(d.startswith("data/hdr_front/timestamp row 12: stamp") and "repeats" in d
               for d in details)  # fmt: skip
    assert res.images["front"] == res.images["left"] - 3


def test_nan_timestamp_row_is_a_reject(rec: Path) -> None:
    ts = _array(rec, "hdr_left/timestamp")
    ts[3] = np.nan
    res, rejects = _ingest(rec)
    assert res.rejects == {"undecodable_message": 1}
    assert "data/hdr_left/timestamp row 3: timestamp" in rejects[0]["detail"]


def test_missing_lidar_group_with_did_you_mean(rec: Path) -> None:
    (rec / "data" / LIDAR).rename(rec / "data" / "hesai_undistorted")  # the older name
    with pytest.raises(ValueError, match=r"no LiDAR topic group 'hesai_points_undistorted' "
                       r".*did you mean hesai_undistorted\?"):  # fmt: skip
        _ingest(rec)
    res, _ = _ingest(rec, hf=HfConfig(lidar_group="hesai_undistorted"))
    assert res.sweeps > 0


def test_missing_odometry_group_is_a_missing_topic_reject(rec: Path) -> None:
    shutil.rmtree(rec / "data" / "anymal_state_odometry")
    res, rejects = _ingest(rec)
    assert res.rejects == {"missing_topic": 1} and res.odometry == 0
    assert "no odometry topic group 'anymal_state_odometry'" in rejects[0]["detail"]
    assert any("missing_topic" in w for w in res.warnings)


def test_missing_camera_group_is_a_missing_topic_reject(rec: Path) -> None:
    (rec / "data" / "hdr_right").rename(rec / "data" / "hdr_rigth")
    res, rejects = _ingest(rec)
    assert res.rejects == {"missing_topic": 1} and "right" not in res.images
    assert "no camera topic group 'hdr_right'" in rejects[0]["detail"]
    assert "did you mean hdr_rigth" in rejects[0]["detail"]
    assert res.images["front"] > 0 and res.images["left"] > 0


def test_input_identity_follows_the_store_and_the_images(rec: Path) -> None:
    from pipeline.stages.common import input_identity

    before = input_identity(rec)
    assert any(i["path"].endswith("hdr_front") for i in before)  # the image folder
    assert any(i["path"].endswith(".zarray") for i in before)
    (rec / "images" / "hdr_front" / "000003.jpeg").unlink()
    assert input_identity(rec) != before


def test_missing_image_folder_drops_that_camera_only(rec: Path) -> None:
    shutil.rmtree(rec / "images" / "hdr_right")
    res, rejects = _ingest(rec)
    assert res.rejects == {"missing_topic": 1} and "right" not in res.images
    assert rejects[0]["file"] == "images/hdr_right" and res.images["front"] > 0


def test_corrupt_jpeg_is_a_reject(rec: Path) -> None:
    path = rec / "images" / "hdr_left" / "000002.jpeg"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    res, rejects = _ingest(rec)
    assert res.rejects == {"corrupt_jpeg": 1}
    assert rejects[0]["file"] == "images/hdr_left/000002.jpeg"
    assert "row 2 of data/hdr_left" in rejects[0]["detail"]


def test_not_a_store(tmp_path: Path) -> None:
    (tmp_path / "m" / "data").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match=r"no ROS1 \.bag files"):
        _ingest(tmp_path / "m")
    with pytest.raises(ValueError, match="no Zarr store"):
        _ingest(tmp_path / "m", format="hf-zarr")


def test_zarr_v3_store_reads_as_v2(tmp_path_factory: pytest.TempPathFactory,
                                   tmp_path: Path) -> None:
    v2 = mission(tmp_path_factory, "clean", "hf-zarr", 2)
    v3 = mission(tmp_path_factory, "clean", "hf-zarr", 3)
    assert (v2 / "data" / ".zgroup").exists() and (v3 / "data" / "zarr.json").exists()
    res = {v: ingest_recording(m, tmp_path / str(v), INGEST) for v, m in ((2, v2), (3, v3))}
    assert res[3].input_format.startswith("hf-zarr (Zarr v3)")
    for name in ("images", "sweeps", "odometry", "calibration"):
        a, b = (read_index_table(table_path(r.index_dir, name), INDEX_TABLES[name])
                for r in res.values())  # fmt: skip
        assert a.equals(b), name


def test_truncated_points_chunk_costs_its_rows_only(rec: Path) -> None:
    """Was: a truncated blosc chunk crashed the process (SIGSEGV) with no message."""
    chunk = rec / "data" / LIDAR / "points" / "1.0.0"
    size = chunk.stat().st_size
    with chunk.open("r+b") as f:
        f.truncate(500)
    res, rejects = _ingest(rec)
    n = _array(rec, f"{LIDAR}/timestamp").shape[0]
    assert res.rejects == {"bad_pointcloud": n - 16, "damaged_region": 1} and res.sweeps == 16
    detail = next(r["detail"] for r in rejects if r["reason"] == "bad_pointcloud")
    assert f"{chunk}: array {LIDAR}/points chunk 1.0.0: blosc header says {size} " \
           "compressed bytes but the chunk holds 500 (truncated or damaged)" in detail


def test_truncated_pose_chunk_costs_its_rows_only(rec: Path,
                                                  tmp_path_factory: pytest.TempPathFactory) -> None:
    """Was: `RuntimeError: error during blosc decompression: -1` failed the recording."""
    pos = _array(rec, "anymal_state_odometry/pose_pos")
    step = pos.chunks[0]
    chunk = rec / "data" / "anymal_state_odometry" / "pose_pos" / "1.0"
    chunk.write_bytes(chunk.read_bytes()[:100])
    res, rejects = _ingest(rec)
    assert res.odometry == _clean(tmp_path_factory, "odometry", ODOMETRY) - step
    assert res.rejects == {"undecodable_message": step, "damaged_region": 1}
    rows = [r for r in rejects if r["reason"] == "undecodable_message"]
    assert rows[0]["file"] == "data/anymal_state_odometry/pose_pos"
    assert rows[0]["detail"].startswith(f"row {step}: data/anymal_state_odometry/pose_pos rows "
                                        f"{step}..{2 * step - 1} (one chunk) cannot be read")
    (region,) = read_index_table(table_path(res.index_dir, "damage"), DAMAGE).to_pylist()
    assert region["messages"] == step and region["topics"] == ["anymal_state_odometry"]


def test_truncated_timestamp_chunk_costs_its_rows_only(
        rec: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    ts = _array(rec, "hdr_left/timestamp")
    n, step = ts.shape[0], ts.chunks[0]
    (rec / "data" / "hdr_left" / "timestamp" / "0").write_bytes(b"\x02\x01")
    res, _ = _ingest(rec)
    assert res.images["left"] == n - step
    assert res.rejects == {"undecodable_message": step, "damaged_region": 1}
    (region,) = read_index_table(table_path(res.index_dir, "damage"), DAMAGE).to_pylist()
    assert region["file"] == "data/hdr_left/timestamp" and region["messages"] == step
    acc = read_index_table(table_path(res.index_dir, "accounting"), ACCOUNTING).to_pylist()
    left = next(r for r in acc if r["topic"] == "hdr_left")
    assert (left["read"], left["kept"], left["rejected"]) == (n, n - step, step)


@pytest.mark.parametrize("version", [2, 3])
def test_invalid_metadata_json_names_the_file(tmp_path_factory: pytest.TempPathFactory,
                                              tmp_path: Path, version: int) -> None:
    """Was: a bare JSONDecodeError, retried three times."""
    rec = tmp_path / "m"
    shutil.copytree(mission(tmp_path_factory, "clean", "hf-zarr", version), rec)
    meta = rec / "data" / LIDAR / "valid" / (".zarray" if version == 2 else "zarr.json")
    meta.write_text('{"shape": [3')
    with pytest.raises(DataError, match=rf"^{meta}: not valid JSON \(.*\); the store's "
                                        "metadata is damaged$"):  # fmt: skip
        _ingest(rec)


def test_v3_truncated_chunk_is_named(tmp_path_factory: pytest.TempPathFactory,
                                     tmp_path: Path) -> None:
    rec = tmp_path / "m"
    shutil.copytree(mission(tmp_path_factory, "clean", "hf-zarr", 3), rec)
    chunks = sorted((rec / "data" / LIDAR / "points").rglob("c/*/0/0")) or sorted(
        p for p in (rec / "data" / LIDAR / "points").rglob("*") if p.is_file()
        and p.name != "zarr.json")
    chunks[-1].write_bytes(chunks[-1].read_bytes()[:300])
    res, rejects = _ingest(rec)
    assert res.rejects.get("damaged_region") == 1 and res.sweeps > 0
    detail = next(r["detail"] for r in rejects if r["reason"] == "bad_pointcloud")
    assert "(truncated or damaged)" in detail or "zstd" in detail, detail


def test_two_lidars_on_the_one_lidar_group_are_refused(rec: Path) -> None:
    lidars = {"a": {"topic": "/a", "frame": "hesai_lidar"}, "b": {"topic": "/b", "frame": "b"}}
    topics = INGEST.topics.model_copy(update={"lidars": TopicsConfig(lidars=lidars).lidars})
    with pytest.raises(DataError, match=r": the Hugging Face layout holds one LiDAR group "
                       r"\(ingest.hf.lidar_group\); ingest.topics.lidars declares 2$"):
        _ingest(rec, topics=topics)
    assert not (rec.parent / "out").exists() or not list((rec.parent / "out").rglob("*.parquet"))
