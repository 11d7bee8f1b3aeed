"""Every injected fault is recorded in faults.json and is present in the bags as described."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.highlevel.anyreader import AnyReaderError

from pipeline.synth.api import SynthResult, synthesize
from pipeline.synth.faults import FAULT_KINDS, plan_faults
from pipeline.synth.rosio import ros1_typestore
from pipeline.synth.timeline import make_timeline
from schemas.config import SynthConfig
from tests.pipeline.synth.conftest import TINY
from tests.pipeline.synth.helpers import cloud_points, read_topic, stamp_ns, table

FRONT = "/boxi/hdr/front/image_raw/compressed"
LIDAR = "/boxi/hesai/points_undistorted"


def _faults(res: SynthResult, kind: str) -> list[dict[str, Any]]:
    data = json.loads((res.groundtruth_dir / "faults.json").read_text())
    assert data["faults"] == res.faults
    return [f for f in data["faults"] if f["kind"] == kind]


def test_every_requested_kind_is_recorded(faulty: SynthResult) -> None:
    kinds = {f["kind"] for f in faulty.faults}
    assert kinds == set(FAULT_KINDS)
    for f in faulty.faults:
        assert (faulty.mission_dir / f["bag"]).is_file() and f["topic"]


def test_clean_mission_has_no_faults(clean: SynthResult) -> None:
    assert json.loads((clean.groundtruth_dir / "faults.json").read_text())["faults"] == []


def test_corrupt_jpeg(faulty: SynthResult) -> None:
    bad = {f["stamp_ns"] for f in _faults(faulty, "corrupt_jpeg")}
    assert len(bad) == 2
    seen = set()
    for _, msg in read_topic(faulty.bags["hdr_front"], FRONT):
        img = cv2.imdecode(np.asarray(msg.data), cv2.IMREAD_COLOR)
        if stamp_ns(msg.header) in bad:
            assert img is None
            seen.add(stamp_ns(msg.header))
        else:
            assert img is not None and img.shape == (96, 128, 3)
    assert seen == bad
    rows = table(faulty.groundtruth_dir, "images")
    flagged = {s for s, c in zip(rows["header_stamp_ns"], rows["jpeg_corrupt"], strict=True) if c}
    assert flagged == bad


def test_duplicate_and_out_of_order_stamps(faulty: SynthResult) -> None:
    (dup,) = _faults(faulty, "duplicate_stamps")
    (ooo,) = _faults(faulty, "out_of_order_stamps")
    heads = [stamp_ns(m.header) for _, m in read_topic(faulty.bags["hdr_front"], FRONT)]
    values, counts = np.unique(heads, return_counts=True)
    assert values[counts > 1].tolist() == [dup["stamp_ns"]]
    back = [i for i in range(1, len(heads)) if heads[i] < heads[i - 1]]
    assert len(back) == 1 and heads[back[0] - 1] == ooo["stamp_ns"]
    assert heads[back[0]] == ooo["next_stamp_ns"]


def test_camera_gap(faulty: SynthResult) -> None:
    (gap,) = _faults(faulty, "camera_gap")
    assert gap["camera"] == "left" and gap["end_ns"] - gap["start_ns"] == round(0.3 * 3.0 * 1e9)
    topic = "/boxi/hdr/left/image_raw/compressed"
    st = np.array([stamp_ns(m.header) for _, m in read_topic(faulty.bags["hdr_left"], topic)])
    assert not ((st >= gap["start_ns"]) & (st < gap["end_ns"])).any()
    assert np.diff(st).max() >= gap["end_ns"] - gap["start_ns"]
    assert len(st) + len(gap["indices"]) == round((3.0 + 0.3) * 10)


def test_missing_camera_info_and_tf_edge(faulty: SynthResult) -> None:
    (info,) = _faults(faulty, "missing_camera_info")
    with AnyReader([faulty.bags["hdr_right"]], default_typestore=ros1_typestore()) as r:
        topics = {c.topic for c in r.connections}
    assert info["topic"] not in topics and "/boxi/hdr/right/image_raw/compressed" in topics
    (edge,) = _faults(faulty, "missing_tf_edge")
    ((_, static),) = read_topic(faulty.bags["tf_minimal"], "/tf_static")
    edges = {(t.header.frame_id, t.child_frame_id) for t in static.transforms}
    assert (edge["parent"], edge["child"]) not in edges and len(edges) == 5


def test_lidar_faults(faulty_lidar: SynthResult) -> None:
    sweeps = {
        stamp_ns(m.header): m for _, m in read_topic(faulty_lidar.bags["hesai_undist"], LIDAR)
    }
    for f in _faults(faulty_lidar, "nan_points"):
        pts = cloud_points(sweeps[f["stamp_ns"]])
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], 1)
        assert (~np.isfinite(xyz).all(axis=1)).sum() == f["n_nonfinite"] > 0
    (empty,) = _faults(faulty_lidar, "empty_sweep")
    assert sweeps[empty["stamp_ns"]].width == 0 and len(sweeps[empty["stamp_ns"]].data) == 0
    clean = [s for s in sweeps.values() if s.width]
    assert sum(np.isfinite(cloud_points(s)["x"]).all() for s in clean) == len(clean) - 2
    (gap,) = _faults(faulty_lidar, "lidar_gap")
    starts = np.array(table(faulty_lidar.groundtruth_dir, "sweeps")["start_ns"])
    assert not ((starts >= gap["start_ns"]) & (starts < gap["end_ns"])).any()
    assert len(sweeps) + len(gap["indices"]) == 30
    assert np.diff(sorted(sweeps)).max() >= gap["end_ns"] - gap["start_ns"]


@pytest.fixture(scope="module")
def faulty_lidar(faulty: SynthResult, tmp_path_factory: pytest.TempPathFactory) -> SynthResult:
    """The faulty mission's LiDAR faults without the truncation (so the bag reads whole)."""
    cfg = SynthConfig(**{**TINY, "seconds": 3.0, "cameras": ["front"],
                         "faults": ["nan_points", "empty_sweep", "lidar_gap"]})  # fmt: skip
    return synthesize(tmp_path_factory.mktemp("lidar"), cfg, "warehouse")


def test_truncated_bag(faulty: SynthResult) -> None:
    (cut,) = [f for f in faulty.faults if f["kind"] == "truncated_bag"]
    path = faulty.mission_dir / cut["bag"]
    assert path.stat().st_size == cut["bytes_after"] == int(0.75 * cut["bytes_before"])
    with (
        pytest.raises(AnyReaderError, match=r"index|chunk|truncat|Bag|read"),
        AnyReader([path], default_typestore=ros1_typestore()) as r,
    ):
        list(r.messages())


def test_unknown_fault_is_refused() -> None:
    tl = make_timeline(SynthConfig(**TINY), ["front"], np.random.default_rng(0))
    with pytest.raises(ValueError, match="unknown fault kind"):
        plan_faults(["melted_sensor"], tl, ["front"])


def test_unknown_fault_fails_config_validation(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="faults"):
        SynthConfig(faults=["melted_sensor"])  # type: ignore[list-item]
