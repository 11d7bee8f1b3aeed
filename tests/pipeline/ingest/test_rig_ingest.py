"""Ingest of rig variants the default generator does not make: cameras of any name with their
own topics and frames, ten cameras, raw and PNG images, unsupported encodings, a CameraInfo
that changes mid-recording, split bags, a mission folder that is a rosbag2 bag."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from packets.poses import make_T, quat_to_rot, rot_to_quat
from pipeline.ingest.core.stream import CameraImage
from pipeline.ingest.index.ingest_result import IngestResult
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.sweep_reader import iter_sweeps
from pipeline.synth.api import synthesize
from pipeline.synth.variants_rig import (
    ODOMETRY_T,
    POSE_COV_T,
    POSE_T,
    TEN_CAMERAS,
    change_camera_info,
    odometry_as,
    rig_topics,
    split_bags,
    to_raw_images,
    to_rosbag2_folder,
)
from schemas.config import IngestConfig, SynthConfig, TopicsConfig
from schemas.errors import DataError
from schemas.recording_index import (
    CALIBRATION,
    IMAGES,
    ODOMETRY,
    REJECTS,
    SWEEPS,
    read_index_table,
    table_path,
)

SMALL: dict[str, Any] = {"image_width": 96, "image_height": 64, "points_per_sweep": 256,
                         "seconds": 0.6, "seed": 5, "depth_maps": False}  # fmt: skip
OUT = {"out_height": 42, "out_width": 56}


def _mission(root: Path, name: str, cameras: list[str], topics: TopicsConfig | None = None
             ) -> Path:  # fmt: skip
    synthesize(root, SynthConfig(cameras=cameras, **SMALL), "corridor", name, topics)
    return root / name


@pytest.fixture(scope="module")
def front(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-camera mission (written once; tests copy it before changing it)."""
    return _mission(tmp_path_factory.mktemp("rig"), "front", ["front"])


def _copy(mission: Path, tmp: Path, name: str = "m") -> Path:
    dst = tmp / name
    shutil.copytree(mission, dst)
    return dst


def _ingest(mission: Path, out: Path, cfg: IngestConfig) -> tuple[IngestResult, list[CameraImage]]:
    images: list[CameraImage] = []
    return ingest_recording(mission, out, cfg, images.append), images


def _rows(res: IngestResult, name: str, schema: Any) -> list[dict[str, Any]]:
    return read_index_table(table_path(res.index_dir, name), schema).to_pylist()


def test_camera_of_any_name_with_its_own_topics(tmp_path: Path) -> None:
    cams = ["alphasense_front_left", "zed2i_right"]
    own = rig_topics(cams)
    topics = TopicsConfig(per_camera=own)
    mission = _mission(tmp_path, "named", cams, topics)
    cfg = IngestConfig(cameras=cams, topics=topics, **OUT)
    res, _images = _ingest(mission, tmp_path / "out", cfg)
    assert res.rejects == {}
    assert set(res.images) == set(cams) and min(res.images.values()) >= 5
    rows = _rows(res, "images", IMAGES)
    assert {r["topic"] for r in rows} == {own[c].image for c in cams}
    assert own["alphasense_front_left"].image == (
        "/gt_box/alphasense_driver_node/front_left/color/image/compressed")
    # the template alone does not find them
    with pytest.raises(ValueError, match="camera image topic"):
        ingest_recording(mission, tmp_path / "out2", IngestConfig(cameras=cams, **OUT))


def test_ten_camera_rig(tmp_path: Path) -> None:
    cams = list(TEN_CAMERAS)
    topics = TopicsConfig(per_camera=rig_topics(cams))
    mission = _mission(tmp_path, "ten", cams, topics)
    res, images = _ingest(mission, tmp_path / "out", IngestConfig(cameras=cams, topics=topics,
                                                                  **OUT))  # fmt: skip
    assert res.rejects == {}
    assert sorted(res.images) == sorted(cams)
    assert len({img.camera for img in images}) == 10


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "mono16",
                                      "bayer_rggb8", "bayer_gbrg16", "png"])
def test_raw_and_png_images_match_the_jpeg_recording(front: Path, tmp_path: Path,
                                                     encoding: str) -> None:  # fmt: skip
    cfg = IngestConfig(cameras=["front"], **OUT)
    ref, ref_images = _ingest(front, tmp_path / "ref", cfg)
    mission = _copy(front, tmp_path)
    to_raw_images(mission, encoding, pad_bytes=3 if encoding != "png" else 0,
                  big_endian=encoding == "mono16")
    raw_topic = "/boxi/hdr/front/image_raw"
    topics = TopicsConfig(per_camera={} if encoding == "png" else {"front": {"image": raw_topic}})
    res, images = _ingest(mission, tmp_path / "out", IngestConfig(cameras=["front"],
                                                                  topics=topics, **OUT))
    assert res.rejects == {} and res.images == ref.images
    for a, b in zip(images, ref_images, strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.K_out, b.K_out)
        diff = np.abs(a.image.astype(int) - b.image.astype(int))
        if encoding.startswith("mono"):  # grey against colour: compare luminance
            diff = np.abs(a.image[..., 1].astype(int) - b.image.mean(axis=2)).astype(int)
        # the same pixels (lossless formats of the JPEG's decode), up to Bayer interpolation
        limit = 40 if "bayer" in encoding else 12
        assert float(np.median(diff)) <= limit / 4 and float(diff.mean()) < limit


def test_unsupported_encoding_is_refused_once_not_as_damage(front: Path, tmp_path: Path) -> None:
    mission = _copy(front, tmp_path)
    to_raw_images(mission, "rgb8")
    bag = next(mission.glob("*_hdr_front.bag"))
    data = bag.read_bytes().replace(b"rgb8", b"yuv4")  # every message's encoding field
    bag.write_bytes(data)
    topics = TopicsConfig(per_camera={"front": {"image": "/boxi/hdr/front/image_raw"}})
    res, images = _ingest(mission, tmp_path / "out", IngestConfig(cameras=["front"],
                                                                  topics=topics, **OUT))
    assert images == [] and "corrupt_jpeg" not in res.rejects
    assert res.rejects["unsupported_image"] >= 5
    told = [w for w in res.warnings if "'yuv4'" in w]
    assert len(told) == 1 and "/boxi/hdr/front/image_raw" in told[0]


def test_images_follow_a_camera_info_that_changes(front: Path, tmp_path: Path) -> None:
    cfg = IngestConfig(cameras=["front"], **OUT)
    ref, ref_images = _ingest(front, tmp_path / "ref", cfg)
    mission = _copy(front, tmp_path)
    cut = ref_images[len(ref_images) // 2].stamp_ns
    assert change_camera_info(mission, "hdr_front", cut, scale=0.5) > 0
    res, images = _ingest(mission, tmp_path / "out", cfg)
    assert res.rejects == {} and res.images == ref.images
    changed = [w for w in res.warnings if "changes at stamp" in w]
    assert len(changed) == 1 and "96x64" in changed[0] and "48x32" in changed[0]
    before = [i for i in images if i.stamp_ns < cut]
    after = [i for i in images if i.stamp_ns >= cut]
    assert before and after
    ref_by = {i.stamp_ns: i for i in ref_images}
    for img in before:
        np.testing.assert_array_equal(img.image, ref_by[img.stamp_ns].image)
    for img in after:  # its own calibration: the same view, rectified from half the pixels
        ref_img = ref_by[img.stamp_ns]
        assert not np.array_equal(img.K_out, ref_img.K_out)  # K of its own CameraInfo
        np.testing.assert_allclose(img.K_out, ref_img.K_out, atol=1.0)  # crop rounding
        assert img.image.shape == ref_img.image.shape
        assert np.abs(img.image.astype(int) - ref_img.image.astype(int)).mean() < 16
    # an image that contradicts its own CameraInfo is rejected with a named reason
    raw = _copy(front, tmp_path, "raw")
    to_raw_images(raw, "bgr8")
    change_camera_info_only(raw, cut)
    topics = TopicsConfig(per_camera={"front": {"image": "/boxi/hdr/front/image_raw"}})
    res2, _ = _ingest(raw, tmp_path / "out2", IngestConfig(cameras=["front"], topics=topics,
                                                           **OUT))  # fmt: skip
    assert res2.rejects.get("calibration_mismatch") == len(after)
    assert "corrupt_jpeg" not in res2.rejects


def change_camera_info_only(mission: Path, from_ns: int) -> None:
    """The CameraInfo says half size from `from_ns` on; the raw images stay full size."""
    from pipeline.synth.rosio import ros1_typestore
    from pipeline.synth.variants_rig import INFO_T, rewrite_bag

    ts = ros1_typestore()

    def convert(topic: str, msgtype: str, stamp: int, raw: bytes) -> Any:
        if msgtype != INFO_T:
            return None
        msg = ts.deserialize_ros1(raw, msgtype)
        if int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec) < from_ns:
            return None
        msg = ts.types[INFO_T](**{**{k: getattr(msg, k) for k in msg.__dataclass_fields__},
                                  "width": msg.width // 2, "height": msg.height // 2})
        return topic, msgtype, ts.serialize_ros1(msg, msgtype)

    rewrite_bag(next(mission.glob("*_hdr_front.bag")), convert)


@pytest.mark.parametrize("layout", ["split_bags", "rosbag2_folder"])
def test_split_and_rosbag2_missions_read_as_one_stream(front: Path, tmp_path: Path,
                                                       layout: str) -> None:  # fmt: skip
    cfg = IngestConfig(cameras=["front"], **OUT)
    ref, ref_images = _ingest(front, tmp_path / "ref", cfg)
    mission = _copy(front, tmp_path)
    if layout == "split_bags":
        split_bags(mission, parts=3)
        assert len(list(mission.glob("*_2.bag"))) == 4
    else:
        assert len(to_rosbag2_folder(mission)) == 4
    res, images = _ingest(mission, tmp_path / "out", cfg)
    assert res.rejects == {} and res.images == ref.images and res.sweeps == ref.sweeps
    assert [i.stamp_ns for i in images] == [i.stamp_ns for i in ref_images]
    for a, b in zip(images, ref_images, strict=True):
        np.testing.assert_array_equal(a.image, b.image)
    assert not [r for r in _rows(res, "rejects", REJECTS) if r["reason"] == "stream_gap"]
    sweeps = _rows(res, "sweeps", SWEEPS)
    read = list(iter_sweeps(mission, sweeps))  # as packets reads them
    assert len(read) == len(sweeps) > 0


def test_split_parts_are_read_in_number_order(tmp_path: Path) -> None:
    from pipeline.ingest.sources.bags import find_bags

    names = ["m_hesai_10.bag", "m_hesai_2.bag", "m_hesai_1.bag", "m_hdr_front_0.bag"]
    for n in names:
        (tmp_path / n).write_bytes(b"")
    assert [p.name for p in find_bags(tmp_path)] == [
        "m_hdr_front_0.bag", "m_hesai_1.bag", "m_hesai_2.bag", "m_hesai_10.bag"]


@pytest.mark.parametrize("msgtype", [POSE_T, POSE_COV_T])
def test_odometry_from_pose_messages(front: Path, tmp_path: Path, msgtype: str) -> None:
    """PoseStamped / PoseWithCovarianceStamped odometry, read by the type the bag declares:
    the same odometry table as the nav_msgs/Odometry recording (the pose is the base frame's)."""
    from rosbags.rosbag1 import Reader

    cfg = IngestConfig(cameras=["front"], **OUT)
    ref, ref_images = _ingest(front, tmp_path / "ref", cfg)
    mission = _copy(front, tmp_path)
    assert odometry_as(mission, msgtype) == ref.odometry > 5
    declared = set()
    for bag in mission.glob("*.bag"):
        with Reader(bag) as reader:
            declared |= {c.msgtype for c in reader.connections if c.topic == cfg.topics.odometry}
    assert declared == {msgtype}
    res, images = _ingest(mission, tmp_path / "out", cfg)
    assert res.rejects == {} and res.odometry == ref.odometry and res.images == ref.images
    assert _rows(res, "odometry", ODOMETRY) == _rows(ref, "odometry", ODOMETRY)
    assert [i.stamp_ns for i in images] == [i.stamp_ns for i in ref_images]


def test_pose_child_frame_other_than_base_is_rebased(front: Path, tmp_path: Path) -> None:
    """Odometry whose child frame is the LiDAR's: re-based to the base frame through
    /tf_static, the same poses as the recording's own (to float precision)."""
    from pipeline.synth.rosio import ros1_typestore
    from pipeline.synth.variants_rig import rewrite_bag

    cfg = IngestConfig(cameras=["front"], **OUT)
    ref, _ = _ingest(front, tmp_path / "ref", cfg)
    calib = {r["sensor"]: r for r in _rows(ref, "calibration", CALIBRATION)}
    T_base_lidar = np.asarray(calib["lidar"]["T_base_sensor"]).reshape(4, 4)
    mission = _copy(front, tmp_path)
    ts = ros1_typestore()
    m = ts.types

    def convert(topic: str, mtype: str, stamp: int, raw: bytes) -> Any:
        if mtype != ODOMETRY_T:
            return None
        odo = ts.deserialize_ros1(raw, mtype)
        p, q = odo.pose.pose.position, odo.pose.pose.orientation
        T = make_T(quat_to_rot(np.array([q.x, q.y, q.z, q.w])), np.array([p.x, p.y, p.z]))
        T = T @ T_base_lidar  # T_odom_lidar
        qq = rot_to_quat(T[:3, :3])
        pose = m["geometry_msgs/msg/Pose"](
            position=m["geometry_msgs/msg/Point"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            orientation=m["geometry_msgs/msg/Quaternion"](x=qq[0], y=qq[1], z=qq[2], w=qq[3]))
        cov = m["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
        odo = m[ODOMETRY_T](header=odo.header, child_frame_id="hesai_lidar", pose=cov,
                            twist=odo.twist)
        return topic, mtype, ts.serialize_ros1(odo, mtype)

    bag = next(b for b in mission.glob("*.bag") if "anymal" in b.name or "odom" in b.name)
    rewrite_bag(bag, convert)
    res, _ = _ingest(mission, tmp_path / "out", cfg)
    assert res.rejects == {} and res.odometry == ref.odometry
    got, want = _rows(res, "odometry", ODOMETRY), _rows(ref, "odometry", ODOMETRY)
    np.testing.assert_allclose([r["position"] for r in got], [r["position"] for r in want],
                               atol=1e-9)
    dots = np.abs(np.sum(np.array([r["quat_xyzw"] for r in got])
                         * np.array([r["quat_xyzw"] for r in want]), axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)


def test_odometry_topic_of_another_type_names_the_key(front: Path, tmp_path: Path) -> None:
    cfg = IngestConfig(cameras=["front"], topics=TopicsConfig(
        odometry="/boxi/hdr/front/camera_info"), **OUT)  # fmt: skip
    with pytest.raises(DataError, match=r"odometry topic /boxi/hdr/front/camera_info "
                       r"\(ingest.topics.odometry\) is sensor_msgs/msg/CameraInfo"):
        _ingest(front, tmp_path / "out", cfg)


def test_missing_base_frame_names_the_config_key(front: Path, tmp_path: Path) -> None:
    from pipeline.ingest.errors import MissingTransformError

    cfg = IngestConfig(cameras=["front"], topics=TopicsConfig(base_frame="base_link"), **OUT)
    with pytest.raises(MissingTransformError, match=r"the base frame 'base_link' is in no "
                       r"transform of /tf_static: set ingest.topics.base_frame") as err:
        _ingest(front, tmp_path / "out", cfg)
    assert str(err.value).count("\n") == 0


def test_disconnected_sensor_frame_names_both_keys(tmp_path: Path) -> None:
    from pipeline.ingest.errors import MissingTransformError
    from tests.pipeline.ingest.bagkit import Mission, write_mission

    mission = write_mission(tmp_path, Mission(drop_edge="hdr_base"))
    cfg = IngestConfig(cameras=["front"], out_height=28, out_width=42)
    with pytest.raises(MissingTransformError, match=r"set ingest.topics.base_frame \(now "
                       r"'base'\) or ingest.topics.per_camera.front.frame \(else the template "
                       r"ingest.topics.camera_frame\) \(now 'hdr_front'\)"):
        ingest_recording(mission, tmp_path / "out", cfg)
    own = TopicsConfig(per_camera={"front": {"frame": "hdr_front"}})
    with pytest.raises(MissingTransformError, match=r"or ingest.topics.per_camera.front.frame "
                       r"\(now 'hdr_front'\)"):
        ingest_recording(mission, tmp_path / "out2", cfg.model_copy(update={"topics": own}))
