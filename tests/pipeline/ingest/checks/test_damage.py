"""Nothing lost silently: damaged bags are read around the damage, and every message is counted.

Each test reproduces one case of the damage audit (issue 16) and failed before its fix.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.ingest_audit import accounting_gaps, message_times, silent_losses
from bench.support.fuzz_cases import chunk_spans, flip_bytes
from pipeline.ingest.calib.camera import (
    CorruptImageError,
    build_rectifier,
    camera_from_info,
    check_jpeg,
)
from pipeline.ingest.recording import ingest_recording
from pipeline.select import select_views
from schemas.config import SelectConfig
from schemas.recording_index import (
    ACCOUNTING,
    DAMAGE,
    ODOMETRY,
    REJECTS,
    SWEEPS,
    read_index_table,
    table_path,
)
from tests.pipeline.ingest.bagkit import CAM_H, CAM_W, D_RAW, K_RAW, Mission, _jpeg, write_mission
from tests.pipeline.synthkit import INGEST, recording

CFG = INGEST.model_copy(update={"cameras": ["front"]})
LIDAR, ODOM = "/boxi/hesai/points_undistorted", "/anymal/state_estimator/odometry"
POSE_TOPICS = (ODOM, "/tf")


def _rows(idx: Path, name: str, schema: object) -> list[dict]:
    return read_index_table(table_path(idx, name), schema).to_pylist()  # type: ignore[arg-type]


def test_one_missing_byte_in_the_odometry_bag_keeps_the_recording(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """Was: odometry taken from /tf as well (topic list unknown), every stamp twice, select
    failed with 'pose stamps must be strictly increasing'."""
    src = recording(tmp_path_factory, "clean")
    clean = ingest_recording(src, tmp_path / "clean_out", INGEST)
    mission = tmp_path / "clean"
    shutil.copytree(src, mission)
    bag = mission / "clean_anymal_state.bag"
    bag.write_bytes(bag.read_bytes()[:-1])
    res = ingest_recording(mission, tmp_path / "out", INGEST)
    poses = [r["stamp_ns"] for r in _rows(res.index_dir, "odometry", ODOMETRY)]
    assert len(poses) == len(set(poses))
    assert poses == [r["stamp_ns"] for r in _rows(clean.index_dir, "odometry", ODOMETRY)]
    assert select_views(res.index_dir, SelectConfig(), INGEST).accepted > 0
    assert accounting_gaps(res.index_dir, POSE_TOPICS) == {}


def test_damaged_first_chunk_keeps_every_other_chunk(tmp_path: Path) -> None:
    """Was: 30 flipped bytes in the first chunk of the LiDAR bag lost all sweeps, silently."""
    clean_dir = write_mission(tmp_path / "a", Mission(points=2000))
    mission = write_mission(tmp_path / "b", Mission(points=2000))
    bag = mission / "m0_hesai_undist.bag"
    data = bag.read_bytes()
    assert len(chunk_spans(data)) >= 5
    _, data_at, _ = chunk_spans(data)[0]
    bag.write_bytes(flip_bytes(data, np.random.default_rng(0), n=30, at=data_at + 64)[0])
    cfg = CFG.model_copy(update={"out_height": 28, "out_width": 42})
    clean = ingest_recording(clean_dir, tmp_path / "clean", cfg)
    res = ingest_recording(mission, tmp_path / "out", cfg)
    (region,) = _rows(res.index_dir, "damage", DAMAGE)
    assert region["file"] == "m0_hesai_undist.bag" and region["topics"] == [LIDAR]
    assert region["byte_start"] == chunk_spans(data)[0][0] and region["messages"] >= 1
    kept = [r["stamp_ns"] for r in _rows(res.index_dir, "sweeps", SWEEPS)]
    every = [r["stamp_ns"] for r in _rows(clean.index_dir, "sweeps", SWEEPS)]
    lost = [s for s in every if region["first_ns"] <= s <= region["last_ns"]]
    assert kept == [s for s in every if s not in lost] and len(lost) == region["messages"]
    assert any("damaged_region" in w and "could have held" in w for w in res.warnings)
    clean_times = message_times(clean_dir, [LIDAR, ODOM, "/boxi/hdr/front/image_raw/compressed"])
    assert silent_losses(clean_times, res.index_dir) == {}
    assert accounting_gaps(res.index_dir, POSE_TOPICS) == {}


def test_jpeg_with_corrupt_entropy_data_is_rejected() -> None:
    """Was: libjpeg printed 'Corrupt JPEG data' and OpenCV returned a smeared image."""
    raw = _jpeg(3)
    start = int(np.flatnonzero((raw[:-1] == 0xFF) & (raw[1:] == 0xDA))[0]) + 20
    bad = raw.copy()
    inside = np.arange(start, raw.size - 4)
    inside = inside[(raw[inside] != 0xFF) & (raw[inside - 1] != 0xFF)]
    rng = np.random.default_rng(1)
    where = rng.choice(inside, 6, replace=False)
    bad[where] = np.where(raw[where] == 0x00, 0x01, raw[where] ^ 0x3C)
    bad[where] = np.where(bad[where] == 0xFF, 0xFE, bad[where])
    check_jpeg(bad, "x")  # the marker walk alone does not see it
    assert cv2.imdecode(bad, cv2.IMREAD_COLOR) is not None  # and OpenCV decodes it
    msg = type("CI", (), {"distortion_model": "equidistant", "K": K_RAW.ravel(), "D": D_RAW,
                          "width": CAM_W, "height": CAM_H,
                          "header": type("H", (), {"frame_id": "hdr_front"})()})()
    rect = build_rectifier(camera_from_info("front", msg, "x"), (28, 42))
    rect.apply(raw, "good")
    with pytest.raises(CorruptImageError, match=r"bag: /cam at stamp 5 ns: JPEG data corrupt"):
        rect.apply(bad, "bag: /cam at stamp 5 ns")


def test_accounting_holds_on_every_fault_of_the_synthetic_recording(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    res = ingest_recording(recording(tmp_path_factory, "faulty"), tmp_path / "out", INGEST)
    assert res.unaccounted == {}
    assert accounting_gaps(res.index_dir, POSE_TOPICS) == {}


def test_nan_rows_are_counted_not_rejected_even_in_a_dense_cloud(tmp_path: Path) -> None:
    """Missing returns (NaN rows of a non-dense cloud) are statistics; a dense cloud holding
    them contradicts itself: the same, and one warning for the topic."""
    cfg = CFG.model_copy(update={"out_height": 28, "out_width": 42})
    res = ingest_recording(write_mission(tmp_path / "a", Mission(nan_rows=7)), tmp_path / "o", cfg)
    assert "nonfinite_points" not in res.rejects
    assert {r["n_nonfinite"] for r in _rows(res.index_dir, "sweeps", SWEEPS)} == {7}
    assert not [w for w in res.warnings if "is_dense" in w]
    dense = write_mission(tmp_path / "b", Mission(nan_rows=7, dense=True))
    res = ingest_recording(dense, tmp_path / "p", cfg)
    assert "nonfinite_points" not in res.rejects
    rows = _rows(res.index_dir, "sweeps", SWEEPS)
    assert len(rows) == 10 and {r["n_nan"] for r in rows} == {7}
    dense_notes = [w for w in res.warnings if "is_dense" in w]
    assert len(dense_notes) == 1 and "7 invalid returns (7 NaN, 0 +Inf, 0 -Inf" in dense_notes[0]


def test_reject_reasons_name_the_fault(tmp_path: Path) -> None:
    """Was: 'missing_camera_info' for a zero focal length."""
    m = Mission(cameras=("front", "left"), zero_focal={"left"})
    cfg = CFG.model_copy(update={"cameras": ["front", "left"], "out_height": 28,
                                 "out_width": 42})
    res = ingest_recording(write_mission(tmp_path, m), tmp_path / "out", cfg)
    (row,) = [r for r in _rows(res.index_dir, "rejects", REJECTS) if r["topic"].endswith("info")]
    assert row["reason"] == "bad_camera_info" and "K=" in row["detail"]
    assert row["topic"] == "/boxi/hdr/left/camera_info" and row["stamp_ns"] > 0


def _rename_topics(bag: Path, old: str, new: str) -> None:
    """Rewrite a ROS1 bag with `old` replaced by `new` in every topic name."""
    from rosbags.rosbag1 import Reader, Writer

    tmp = bag.with_name("renamed.bag")
    with Reader(bag) as src, Writer(tmp) as dst:
        conns = {c.id: dst.add_connection(c.topic.replace(old, new), c.msgtype,
                                          msgdef=c.msgdef.data, md5sum=c.digest)
                 for c in src.connections}  # fmt: skip
        for conn, stamp, raw in src.messages():
            dst.write(conns[conn.id], stamp, raw)
    tmp.replace(bag)


def test_renamed_camera_topics_are_named_with_a_did_you_mean(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """Was: the camera dropped with a warning but without the README's did-you-mean."""
    mission = tmp_path / "clean"
    shutil.copytree(recording(tmp_path_factory, "clean"), mission)
    _rename_topics(mission / "clean_hdr_front.bag", "/hdr/front/", "/hdr/front_cam/")
    res = ingest_recording(mission, tmp_path / "out", INGEST)
    told = " ".join(res.warnings)
    assert "did you mean /boxi/hdr/front_cam/camera_info" in told
    assert "did you mean /boxi/hdr/front_cam/image_raw/compressed" in told
    assert set(res.images) == {"left", "right"}


def test_indexed_reading_of_several_topics_of_one_bag(tmp_path: Path) -> None:
    """Messages of two connections of one bag come with their own topic, in log-time order."""
    from pipeline.ingest.sources.bags import BagFile

    mission = write_mission(tmp_path, Mission())
    bag = BagFile(mission / "m0_hdr_front.bag", mission)
    topics = ["/boxi/hdr/front/camera_info", "/boxi/hdr/front/image_raw/compressed"]
    msgs = list(bag.messages(topics))
    assert [m.topic for m in msgs].count(topics[1]) == 10 and bag.regions == []
    assert {m.topic for m in msgs} == set(topics)
    assert [m.bag_time_ns for m in msgs] == sorted(m.bag_time_ns for m in msgs)
    for m in msgs:
        bag.deserialize(m)  # each raw message decodes as its own topic's type


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("style", ["x_nan", "posinf", "neginf", "zero"])
def test_missing_returns_of_other_drivers_keep_every_sweep(tmp_path: Path, style: str,
                                                           dense: bool) -> None:
    """x-only NaN (the other fields 0), +-Inf or zeros for a missing return: invalid returns,
    dropped and counted by kind; never a damaged message, dense flag or not."""
    cfg = CFG.model_copy(update={"out_height": 28, "out_width": 42})
    m = write_mission(tmp_path / "m", Mission(nan_rows=9, invalid=style, dense=dense))
    res = ingest_recording(m, tmp_path / "o", cfg)
    assert not {"nonfinite_points", "bad_pointcloud", "empty_sweep"} & set(res.rejects)
    rows = _rows(res.index_dir, "sweeps", SWEEPS)
    column = {"x_nan": "n_nan", "posinf": "n_posinf", "neginf": "n_neginf", "zero": "n_zero"}
    assert len(rows) == 10 and {r[column[style]] for r in rows} == {9}
    told = [w for w in res.warnings if "is_dense" in w]
    assert len(told) == (1 if dense and style != "zero" else 0)


def test_damaged_camera_chunk_names_every_topic_it_held(tmp_path: Path) -> None:
    """Was: a damaged LZ4 chunk holding the only camera_info and the first images dropped the
    camera; the damage row named camera_info only and the image topic was absent from the
    accounting. Now both come from the chunk index."""
    mission = write_mission(tmp_path / "b", Mission(points=200))
    bag = mission / "m0_hdr_front.bag"
    data = bag.read_bytes()
    _, data_at, _ = chunk_spans(data)[0]
    bag.write_bytes(flip_bytes(data, np.random.default_rng(0), n=30, at=data_at + 64)[0])
    cfg = CFG.model_copy(update={"out_height": 28, "out_width": 42})
    res = ingest_recording(mission, tmp_path / "out", cfg)
    image = "/boxi/hdr/front/image_raw/compressed"
    regions = [r for r in _rows(res.index_dir, "damage", DAMAGE) if r["file"] == bag.name]
    assert regions and image in regions[0]["topics"] and len(regions[0]["topics"]) >= 2
    acc = {(r["file"], r["topic"]) for r in _rows(res.index_dir, "accounting", ACCOUNTING)}
    assert (bag.name, image) in acc
