"""Several named LiDARs (`ingest.topics.lidars`): every one indexed with its own point-time
decision and calibration, the views' LiDAR chosen by `select.lidar`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from packets.poses import make_T, quat_to_rot
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.static import frame_key
from pipeline.ingest.sources.sweep_reader import load_sweep
from pipeline.select import select_views
from pipeline.synth.api import synthesize
from pipeline.synth.variants_rig import add_lidar
from schemas.config import IngestConfig, M3GDConfig, SelectConfig, SynthConfig, TopicsConfig
from schemas.recording_index import (
    CALIBRATION,
    CHECKS,
    SELECTION,
    SWEEPS,
    read_index_table,
    table_path,
)

SMALL = {"image_width": 96, "image_height": 64, "points_per_sweep": 256, "seconds": 0.6,
         "seed": 5, "depth_maps": False}  # fmt: skip
OUT = {"out_height": 42, "out_width": 56}
FIRST = ("/boxi/hesai/points_undistorted", "hesai_lidar")
SECOND = ("/livox/lidar", "livox_frame")
T_FIRST_SECOND = make_T(quat_to_rot([0.0, 0.0, np.sin(0.4), np.cos(0.4)]), [0.1, -0.2, 0.3])
"""The second LiDAR's pose in the first's frame (yawed 0.8 rad, offset)."""


@pytest.fixture(scope="module")
def two(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A one-camera mission with a second LiDAR, ingested with both declared (the second
    with its point times switched off); (mission, index folder)."""
    root = tmp_path_factory.mktemp("lidars")
    synthesize(root, SynthConfig(cameras=["front"], **SMALL), "corridor", "m")
    assert add_lidar(root / "m", FIRST, SECOND, T_FIRST_SECOND) >= 5
    res = ingest_recording(root / "m", root / "out", _cfg())
    assert res.rejects == {}
    return root / "m", res.index_dir


def _cfg() -> IngestConfig:
    lidars = {"hesai": {"topic": FIRST[0], "frame": FIRST[1]},
              "livox": {"topic": SECOND[0], "frame": SECOND[1], "point_time": "none"}}
    return IngestConfig(cameras=["front"], topics=TopicsConfig(lidars=lidars), **OUT)


def test_every_lidar_is_indexed_with_its_own_convention(two: tuple[Path, Path]) -> None:
    _, idx = two
    rows = read_index_table(table_path(idx, "sweeps"), SWEEPS).to_pylist()
    by = {n: [r for r in rows if r["lidar"] == n] for n in ("hesai", "livox")}
    assert len(by["hesai"]) == len(by["livox"]) >= 5 and len(rows) == 2 * len(by["hesai"])
    assert [r["sweep"] for r in rows] == list(range(len(rows)))  # numbered together
    for n, topic in (("hesai", FIRST[0]), ("livox", SECOND[0])):
        assert {r["topic"] for r in by[n]} == {topic}
        stamps = [r["stamp_ns"] for r in by[n]]
        assert stamps == sorted(set(stamps))
    assert {r["time_field"] for r in by["hesai"]} == {"timestamp"}  # auto: inferred
    assert {r["time_field"] for r in by["livox"]} == {""}  # none: header stamps
    checks = read_index_table(table_path(idx, "checks"), CHECKS).to_pylist()
    states = {r["topic"]: r["state"] for r in checks if r["check"] == "point_time"}
    assert states == {FIRST[0]: "on", SECOND[0]: "off"}


def test_each_lidar_has_its_extrinsic_and_its_points_agree_in_base(
        two: tuple[Path, Path]) -> None:  # fmt: skip
    mission, idx = two
    calib = {r["sensor"]: r for r in
             read_index_table(table_path(idx, "calibration"), CALIBRATION).to_pylist()}
    assert {"hesai", "livox"} <= set(calib) and "lidar" not in calib
    T = {n: np.reshape(calib[n]["T_base_sensor"], (4, 4)) for n in ("hesai", "livox")}
    np.testing.assert_allclose(T["livox"], T["hesai"] @ T_FIRST_SECOND, atol=1e-9)
    rows = read_index_table(table_path(idx, "sweeps"), SWEEPS).to_pylist()
    a = next(r for r in rows if r["lidar"] == "hesai")
    b = next(r for r in rows if r["lidar"] == "livox" and r["stamp_ns"] == a["stamp_ns"])
    pa_, pb = load_sweep(mission, a).xyz, load_sweep(mission, b).xyz
    assert not np.allclose(pa_, pb, atol=1e-2)  # other frames
    in_base = [(p.astype(np.float64) @ T[n][:3, :3].T + T[n][:3, 3])
               for p, n in ((pa_, "hesai"), (pb, "livox"))]
    np.testing.assert_allclose(in_base[0], in_base[1], atol=1e-4)


def test_select_takes_the_declared_lidar(two: tuple[Path, Path]) -> None:
    _, idx = two
    sweeps = {r["sweep"]: r for r in
              read_index_table(table_path(idx, "sweeps"), SWEEPS).to_pylist()}
    out = {}
    for name in (None, "hesai", "livox"):
        res = select_views(idx, SelectConfig(lidar=name), _cfg())
        assert res.sweeps_total == len(sweeps) // 2 and res.accepted >= 3
        sel = read_index_table(table_path(idx, "selection"), SELECTION).to_pylist()
        ok = [r for r in sel if r["status"] == "ok"]
        assert {sweeps[r["sweep"]]["lidar"] for r in ok} == {name or "hesai"}
        assert all(sweeps[r["sweep"]]["stamp_ns"] == r["sweep_stamp_ns"] for r in ok)
        out[name or "default"] = ok
    assert out["default"] == out["hesai"]
    for a, b in zip(out["hesai"], out["livox"], strict=True):  # the same instants, two mounts
        assert a["sweep_stamp_ns"] == b["sweep_stamp_ns"] and a["dtau_s"] == b["dtau_s"]
        np.testing.assert_allclose(np.reshape(b["T_cam_lidar"], (4, 4)),
                                   np.reshape(a["T_cam_lidar"], (4, 4)) @ T_FIRST_SECOND,
                                   atol=1e-9)


def test_a_lidar_without_its_topic_names_it(two: tuple[Path, Path], tmp_path: Path) -> None:
    mission, _ = two
    lidars = {"hesai": {"topic": FIRST[0], "frame": FIRST[1]},
              "ouster": {"topic": "/ouster/points", "frame": "os_sensor"}}
    cfg = IngestConfig(cameras=["front"], topics=TopicsConfig(lidars=lidars), **OUT)
    with pytest.raises(ValueError, match="no bag holds the LiDAR 'ouster' topic /ouster/points"):
        ingest_recording(mission, tmp_path / "out", cfg)


def test_single_lidar_config_serializes_as_before() -> None:
    cfg = M3GDConfig()
    dumped = cfg.model_dump(mode="json")
    assert "lidars" not in dumped["ingest"]["topics"] and "lidar" not in dumped["select"]
    rig = cfg.ingest.topics.lidar_rig()
    assert [(x.name, x.topic, x.frame) for x in rig] == [("lidar", FIRST[0], FIRST[1])]
    assert cfg.select.lidar_of(cfg.ingest.topics) == rig[0]


@pytest.mark.parametrize(("data", "message"), [
    ({"ingest": {"topics": {"lidar": "/x", "lidars": {"a": {"topic": "/a", "frame": "a"}}}}},
     "ingest.topics.lidars and ingest.topics.lidar are both set"),
    ({"ingest": {"topics": {"lidars": {"a": {"topic": "/a", "frame": "a"},
                                       "b": {"topic": "/a", "frame": "b"}}}}},
     "two LiDARs share the topic '/a'"),
    ({"ingest": {"cameras": ["front"], "topics": {"lidars": {"front": {"topic": "/a",
                                                                       "frame": "a"}}}}},
     "LiDAR 'front' has the name of a camera"),
    ({"select": {"lidar": "livox"}}, r"select.lidar 'livox' is not a LiDAR .*\['lidar'\]"),
    ({"select": {"lidar": ["lidar", "livox"]}}, r"select.lidar 'livox' is not a LiDAR"),
    ({"select": {"lidar": []}}, "select.lidar is an empty list"),
    ({"select": {"lidar": ["lidar", "lidar"]}}, "names the LiDAR 'lidar' twice"),
    ({"synth": {"second_lidar": True, "format": "hf-zarr"}}, "second_lidar is written as ROS1"),
])
def test_lidar_rig_mistakes_are_named(data: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        M3GDConfig.model_validate(data)


def test_a_list_of_lidars_merges_with_the_first_as_reference() -> None:
    sel = SelectConfig(lidar=["livox", "hesai"])
    topics = _cfg().topics
    assert sel.merges() and [x.name for x in sel.lidars_of(topics)] == ["livox", "hesai"]
    assert sel.lidar_of(topics).name == "livox"
    one = SelectConfig(lidar=["hesai"])  # a list of one is that LiDAR, not a merge
    assert not one.merges() and [x.name for x in one.lidars_of(topics)] == ["hesai"]
    assert "second_lidar" not in M3GDConfig().model_dump(mode="json")["synth"]


def test_frame_key_of_a_named_lidar() -> None:
    cfg = _cfg()
    assert frame_key(cfg, "livox") == "ingest.topics.lidars.livox.frame"
    assert frame_key(IngestConfig(cameras=["front"], **OUT), "lidar") == "ingest.topics.lidar_frame"
