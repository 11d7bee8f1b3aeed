"""Bags read back with AnyReader: topics, types, counts, rates, stamps and the message layouts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from packets.poses import invert_T, make_T, quat_to_rot
from pipeline.synth.api import BAG_SUFFIXES, SynthResult, synthesize
from pipeline.synth.rosio import ros1_typestore
from schemas.config import SynthConfig
from tests.pipeline.synth.helpers import cloud_points, read_topic, stamp_ns, table

CAMS = ("front", "left", "right")


def test_bag_names_and_topics(clean: SynthResult) -> None:
    m = clean.mission
    names = sorted(p.name for p in clean.mission_dir.glob("*.bag"))
    assert names == sorted(f"{m}_{s}.bag" for s in BAG_SUFFIXES)
    expect = {
        "hdr_front": {
            "/boxi/hdr/front/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
            "/boxi/hdr/front/camera_info": "sensor_msgs/msg/CameraInfo",
        },
        "hesai_undist": {"/boxi/hesai/points_undistorted": "sensor_msgs/msg/PointCloud2"},
        "tf_minimal": {"/tf_static": "tf2_msgs/msg/TFMessage", "/tf": "tf2_msgs/msg/TFMessage"},
        "anymal_state": {"/anymal/state_estimator/odometry": "nav_msgs/msg/Odometry"},
    }
    for suffix, topics in expect.items():
        with AnyReader([clean.bags[suffix]], default_typestore=ros1_typestore()) as r:
            assert {c.topic: c.msgtype for c in r.connections} == topics


def test_counts_rates_and_stamps(clean: SynthResult) -> None:
    n_img = round((1.5 + 0.3) * 10)
    for cam in CAMS:
        imgs = read_topic(clean.bags[f"hdr_{cam}"], f"/boxi/hdr/{cam}/image_raw/compressed")
        infos = read_topic(clean.bags[f"hdr_{cam}"], f"/boxi/hdr/{cam}/camera_info")
        assert len(imgs) == len(infos) == n_img == clean.images[cam]
        st = np.array([stamp_ns(m.header) for _, m in imgs])
        assert [t for t, _ in imgs] == st.tolist()  # bag time = header stamp
        assert abs(np.median(np.diff(st)) / 1e9 - 0.1) < 0.01
        assert np.diff(st).min() > 0.05e9
        assert all(m.header.frame_id == f"hdr_{cam}" for _, m in imgs)
        assert all(m.format == "jpg" and bytes(m.data[:2]) == b"\xff\xd8" for _, m in imgs)
    sweeps = read_topic(clean.bags["hesai_undist"], "/boxi/hesai/points_undistorted")
    assert len(sweeps) == 15 == clean.sweeps
    sst = np.array([stamp_ns(m.header) for _, m in sweeps])
    assert [t for t, _ in sweeps] == sst.tolist()
    assert abs(np.median(np.diff(sst)) / 1e9 - 0.1) < 0.002
    odo = read_topic(clean.bags["anymal_state"], "/anymal/state_estimator/odometry")
    ost = np.array([stamp_ns(m.header) for _, m in odo])
    assert len(odo) == clean.odometry and np.allclose(np.diff(ost), 0.05e9)
    first_image = min(
        int(read_topic(clean.bags["hdr_front"], "/boxi/hdr/front/camera_info")[0][0]), sst[0]
    )
    assert ost[0] < first_image and ost[-1] > sst[-1]  # odometry spans every sensor stamp
    gt_sweeps = table(clean.groundtruth_dir, "sweeps")
    assert gt_sweeps["stamp_ns"] == sst.tolist()


def test_delta_tau_is_spread_with_some_rejects(clean: SynthResult) -> None:
    sst = np.array(table(clean.groundtruth_dir, "sweeps")["stamp_ns"])
    ist = np.array(table(clean.groundtruth_dir, "images")["stamp_ns"])
    j = np.abs(ist[:, None] - sst[None, :]).argmin(axis=1)
    dtau = (sst[j] - ist) / 1e9
    inside = np.abs(dtau) <= 0.1
    assert (~inside).sum() >= 3  # cameras start 0.3 s before the LiDAR
    assert np.abs(dtau[inside]).max() <= 0.06
    assert np.std(dtau[inside]) > 0.005


def test_pointcloud_layout(clean: SynthResult) -> None:
    sweeps = read_topic(clean.bags["hesai_undist"], "/boxi/hesai/points_undistorted")
    _, msg = sweeps[3]
    assert msg.point_step == 26 and msg.height == 1 and msg.row_step == 26 * msg.width
    layout = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
    assert layout == [
        ("x", 0, 7, 1),
        ("y", 4, 7, 1),
        ("z", 8, 7, 1),
        ("intensity", 12, 7, 1),
        ("ring", 16, 4, 1),
        ("timestamp", 18, 8, 1),
    ]
    pts = cloud_points(msg)
    assert 0.8 * 2048 < pts.size <= 2048 and msg.header.frame_id == "hesai_lidar"
    assert np.isfinite(pts["x"]).all() and set(np.unique(pts["ring"])) <= set(range(32))
    t = pts["timestamp"]
    assert abs(t[0] - stamp_ns(msg.header) / 1e9) < 1e-6  # header stamp = first point
    assert np.all(np.diff(t) >= 0) and 0.09 < t[-1] - t[0] < 0.1
    assert ((pts["intensity"] >= 0) & (pts["intensity"] <= 255)).all()


def test_camera_info_fields(clean: SynthResult) -> None:
    _, info = read_topic(clean.bags["hdr_left"], "/boxi/hdr/left/camera_info")[0]
    assert info.distortion_model == "equidistant" and info.D.shape == (4,)
    assert (info.width, info.height) == (128, 96)
    K = info.K.reshape(3, 3)
    assert K[0, 0] > 0 and K[2, 2] == 1 and np.allclose(info.R, np.eye(3).ravel())
    assert np.allclose(info.P.reshape(3, 4)[:, :3], K)


def test_tf_static_tree_and_inverted_odom_edge(clean: SynthResult) -> None:
    ((_, static),) = read_topic(clean.bags["tf_minimal"], "/tf_static")
    edges = {(t.header.frame_id, t.child_frame_id) for t in static.transforms}
    assert edges == {
        ("base", "box_base"),
        ("box_base", "hdr_base"),
        ("box_base", "hesai_lidar"),
        ("hdr_base", "hdr_front"),
        ("hdr_base", "hdr_left"),
        ("hdr_base", "hdr_right"),
    }
    tf = read_topic(clean.bags["tf_minimal"], "/tf")
    odo = dict(read_topic(clean.bags["anymal_state"], "/anymal/state_estimator/odometry"))
    t, msg = tf[5]
    (edge,) = msg.transforms
    assert (edge.header.frame_id, edge.child_frame_id) == ("base", "odom")
    tr, q = edge.transform.translation, edge.transform.rotation
    T_base_odom = make_T(quat_to_rot([q.x, q.y, q.z, q.w]), [tr.x, tr.y, tr.z])
    o = odo[t]
    assert (o.header.frame_id, o.child_frame_id) == ("odom", "base")
    p, oq = o.pose.pose.position, o.pose.pose.orientation
    T_odom_base = make_T(quat_to_rot([oq.x, oq.y, oq.z, oq.w]), [p.x, p.y, p.z])
    np.testing.assert_allclose(T_base_odom, invert_T(T_odom_base), atol=1e-9)


def test_groundtruth_poses_cover_every_stamp(clean: SynthResult) -> None:
    poses = set(table(clean.groundtruth_dir, "poses")["stamp_ns"])
    assert set(table(clean.groundtruth_dir, "images")["stamp_ns"]) <= poses
    sw = table(clean.groundtruth_dir, "sweeps")
    assert set(sw["stamp_ns"]) <= poses and set(sw["t_end_ns"]) <= poses


def test_ros2_mcap_copy_has_the_same_messages(tmp_path: Path) -> None:
    cfg = SynthConfig(seconds=0.5, image_width=96, image_height=64, points_per_sweep=256,
                      cameras=["front"], ros2=True)  # fmt: skip
    res = synthesize(tmp_path, cfg, "forest")
    assert res.ros2_dir is not None
    for bag in res.bags.values():
        with AnyReader([bag], default_typestore=ros1_typestore()) as r1:
            one = sorted((c.topic, t) for c, t, _ in r1.messages())
        with AnyReader([res.ros2_dir / bag.stem]) as r2:
            assert all(c.msgtype in r2.typestore.types for c in r2.connections)
            two = sorted((c.topic, t) for c, t, _ in r2.messages())
        assert one == two and len(one) > 0
