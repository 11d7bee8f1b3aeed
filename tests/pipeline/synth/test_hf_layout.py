"""The Hugging Face layout writer: the release's conventions, checked against the ground truth
and against the bags of the same seed (read with rosbags, not with our readers)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import zarr
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from packets.poses import invert_T, make_T, quat_to_rot
from pipeline.synth.api import synthesize
from schemas.config import SynthConfig
from tests.pipeline.ingest.sources.hf.kit import mission
from tests.pipeline.synthkit import SMALL, gt_json


@pytest.fixture(scope="module")
def hf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return mission(tmp_path_factory, "clean", "hf-zarr")


def _root(hf: Path) -> zarr.Group:
    g = zarr.open_group(str(hf / "data"), mode="r", zarr_format=2)
    assert isinstance(g, zarr.Group)
    return g


def test_store_is_zarr_v2_with_topic_groups(hf: Path) -> None:
    assert (hf / "data" / ".zgroup").is_file() and not (hf / "data" / "zarr.json").exists()
    assert not list(hf.glob("*.bag")) and not (hf / ".bags").exists()
    root = _root(hf)
    assert set(root.group_keys()) == {"hdr_front", "hdr_left", "hdr_right", "tf",
                                      "hesai_points_undistorted", "anymal_state_odometry"}
    for name in root.group_keys():
        attrs = dict(root[name].attrs)
        assert {"description", "frame_id", "topic"} <= set(attrs), name
        if name != "tf":
            assert root[name]["timestamp"].dtype == np.float64


def test_images_are_the_bag_jpegs_by_row(hf: Path,
                                         tmp_path_factory: pytest.TempPathFactory) -> None:
    bags = mission(tmp_path_factory, "clean", "rosbag")
    ts = _root(hf)["hdr_left/timestamp"][:]
    with AnyReader([bags / "clean_hdr_left.bag"],
                   default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        conns = [c for c in reader.connections if c.topic.endswith("compressed")]
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    assert len(msgs) == ts.size == len(list((hf / "images" / "hdr_left").iterdir()))
    for i, msg in enumerate(msgs):
        assert (hf / "images" / "hdr_left" / f"{i:06d}.jpeg").read_bytes() == bytes(msg.data)
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec / 1e9
        assert abs(ts[i] - stamp) < 2.5e-7  # float64 seconds near 1.7e9 s


def test_points_padded_and_sliced_by_valid(hf: Path) -> None:
    g = _root(hf)["hesai_points_undistorted"]
    gt = pq.read_table(hf / "groundtruth" / "sweeps.parquet").to_pylist()
    valid, pts = g["valid"][:, 0], g["points"][:]
    assert valid.tolist() == [r["n_points"] for r in gt]
    assert pts.shape[1] == valid.max()  # padded to the longest scan
    for i, v in enumerate(valid):
        assert not pts[i, v:].any() and np.abs(pts[i, :v]).sum() > 0
    assert "timestamp" not in str(g["points"].dtype)  # no per-point time


def test_poses_are_xyzw_arrays_of_the_ground_truth(hf: Path) -> None:
    g = _root(hf)["anymal_state_odometry"]
    gt = pq.read_table(hf / "groundtruth" / "poses.parquet").to_pandas()
    stamps = gt["stamp_ns"].to_numpy()
    sec = g["timestamp"][:]
    ns = np.floor(sec).astype(np.int64) * 1_000_000_000 + np.rint((sec % 1) * 1e9).astype(np.int64)
    near = np.clip(np.searchsorted(stamps, ns), 0, stamps.size - 1)
    near = np.where(np.abs(stamps[near - 1] - ns) < np.abs(stamps[near] - ns), near - 1, near)
    assert np.abs(stamps[near] - ns).max() < 250  # the same stamps, through float64 seconds
    want = gt.iloc[near]
    np.testing.assert_allclose(g["pose_orien"][:], want[["qx", "qy", "qz", "qw"]], atol=1e-12)
    np.testing.assert_allclose(g["pose_pos"][:], want[["px", "py", "pz"]], atol=1e-12)


def test_tf_entries_map_parent_into_child(hf: Path) -> None:
    tf = dict(_root(hf)["tf"].attrs)["tf"]
    for edge in gt_json(hf, "calibration")["edges"]:
        e = tf[edge["child"]]
        assert e["base_frame_id"] == edge["parent"]
        r, t = e["rotation"], e["translation"]
        T = make_T(quat_to_rot([r["x"], r["y"], r["z"], r["w"]]), [t["x"], t["y"], t["z"]])
        np.testing.assert_allclose(T, invert_T(np.asarray(edge["T_parent_child"])), atol=1e-12)


def test_camera_info_attribute(hf: Path) -> None:
    cams = gt_json(hf, "calibration")["cameras"]
    for cam, c in cams.items():
        info = dict(_root(hf)[f"hdr_{cam}"].attrs)["camera_info"]
        assert info["distortion_model"] == "equidistant" and len(info["K"]) == 9
        np.testing.assert_array_equal(np.reshape(info["K"], (3, 3)), c["K"])
        assert (info["width"], info["height"]) == (c["width"], c["height"])


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    cfg = SynthConfig(seed=5, scenes=["corridor"], seconds=0.6, format="hf-zarr",
                      hf_zarr_version=3, depth_maps=False, **SMALL)  # fmt: skip
    a, b = (synthesize(tmp_path / k, cfg, "corridor", "m").mission_dir for k in ("a", "b"))
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert (a / "data" / "zarr.json").is_file() and len(files) > 20
    for rel in files:
        if rel.parts[0] in ("data", "images"):
            assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
