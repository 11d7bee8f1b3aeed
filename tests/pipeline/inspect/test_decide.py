"""Inspect's decisions from evidence (pure): the pose source among moving /tf edges and
odometry topics, the reference LiDAR, a camera's frame, odometry against /tf."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.poses import make_T, quat_to_rot
from pipeline.inspect.decide import (
    agreement_of,
    decide_camera,
    decide_lidars,
    decide_pose,
    is_joint,
    is_world,
    relative_motion,
)
from pipeline.inspect.model import CameraReport, CloudReport, Convention, TfEdge
from pipeline.inspect.tf import shape

MOUNTS = [TfEdge("base", "lidar", True, "/tf_static", 1),
          TfEdge("base", "cam", True, "/tf_static", 1)]  # fmt: skip
SENSORS = ["lidar", "cam"]


def moving(parent: str, child: str, travel: float = 3.0, jump: float = 0.05) -> TfEdge:
    return TfEdge(parent, child, False, "/tf", 50, 20.0, travel, jump)


def wheel(name: str, body: str = "base") -> TfEdge:
    return TfEdge(body, name, False, "/tf", 50, 20.0, 0.0, 0.0)


@pytest.mark.parametrize("frame", ["odom", "map", "world", "odom_combined", "robot_odom"])
def test_world_names(frame: str) -> None:
    assert is_world(frame) and not is_world("base_link") and not is_world("odometer")


def test_joint_names() -> None:
    assert is_joint("wheel_left_link") and is_joint("LF_HIP") and not is_joint("base_link")


@pytest.mark.parametrize("wheels_first", [True, False])
def test_the_pose_is_the_world_edge_not_a_wheel(wheels_first: bool) -> None:
    body = "base" if wheels_first else "trunk"
    mounts = [TfEdge(body, m.child, True, m.topic, 1) for m in MOUNTS]
    edges = [wheel("wheel_left_link", body), wheel("wheel_right_link", body),
             moving("odom", body)]  # fmt: skip
    d = decide_pose(shape(mounts + edges), (), {}, SENSORS)
    assert d.chosen == f"/tf odom->{body}" and not d.ambiguous
    assert d.keys == {"tf": "/tf", "odom_frame": "odom", "base_frame": body}
    assert [c.name for c in d.candidates][1:] == [f"/tf {body}->wheel_left_link",
                                                  f"/tf {body}->wheel_right_link"]


def test_odom_as_the_child_of_base() -> None:
    d = decide_pose(shape([*MOUNTS, wheel("wheel_left_link"), moving("base", "odom")]), (), {},
                    SENSORS)  # fmt: skip
    assert d.keys == {"tf": "/tf", "odom_frame": "odom", "base_frame": "base"}
    assert "published body -> world" in d.candidates[0].evidence


def test_map_to_odom_with_jumps_is_not_the_pose() -> None:
    d = decide_pose(shape([*MOUNTS, moving("map", "odom", 2.0, 0.4), moving("odom", "base")]),
                    (), {}, SENSORS)  # fmt: skip
    assert d.chosen == "/tf odom->base" and not d.ambiguous
    loc = next(c for c in d.candidates if c.name == "/tf map->odom")
    assert any("jumps 0.40 m" in e for e in loc.evidence)
    assert "its body end odom is itself a world frame" in loc.evidence


def test_two_world_edges_to_the_body_are_ambiguous() -> None:
    """Two estimators each publishing a world edge to a separate body frame the sensors hang
    off: nothing tells them apart; the decision says so."""
    mounts = [*MOUNTS, TfEdge("base_b", "cam2", True, "/tf_static", 1)]
    d = decide_pose(shape([*mounts, moving("odom", "base"), moving("odom_b", "base_b")]), (),
                    {}, [*SENSORS, "cam2"])  # fmt: skip
    assert d.ambiguous and "not told apart" in d.reason
    assert d.line().startswith("pose: /tf odom->base (AMBIGUOUS, ")


def test_an_edge_no_sensor_hangs_below_is_not_chosen() -> None:
    d = decide_pose(shape([*MOUNTS, moving("odom", "base"), moving("mocap", "marker")]), (), {},
                    SENSORS)  # fmt: skip
    assert d.chosen == "/tf odom->base" and not d.ambiguous
    assert "no sensor reached through it" in d.candidates[1].evidence


def test_an_odometry_topic_is_preferred_and_its_disagreement_said() -> None:
    tf = shape([*MOUNTS, moving("base", "odom")])
    odo = (("/odom", "odom", "base"),)
    types = {"/odom": "nav_msgs/msg/Odometry"}
    d = decide_pose(tf, odo, types, SENSORS)
    assert d.chosen == "/odom" and not d.ambiguous
    assert d.keys == {"odometry": "/odom", "odom_frame": "odom", "base_frame": "base"}
    ts = list(range(0, 10**9, 10**8))
    poses = [make_T(np.eye(3), [0.3 * i, 0.0, 0.0]) for i in range(len(ts))]
    far = [make_T(np.eye(3), [5.0, 2.0, 0.0]) @ T for T in poses]  # another world origin
    same = agreement_of("/odom", "/tf base->odom", (ts, poses), (ts, far))
    assert same is not None and same.error_m < 1e-9 and same.samples == 10
    scaled = [make_T(np.eye(3), 1.25 * T[:3, 3]) for T in poses]
    off = agreement_of("/odom", "/tf base->odom", (ts, poses), (ts, scaled))
    assert off is not None and off.error_m == pytest.approx(0.25 * 2.7)
    d = decide_pose(tf, odo, types, SENSORS, agreement=(off,))
    assert d.chosen == "/odom" and d.ambiguous and "DISAGREES" in d.reason


def test_an_odometry_topic_off_the_tree_yields_to_an_edge_to_the_sensors() -> None:
    tf = shape([*MOUNTS, moving("odom", "base")])
    odo = (("/odom", "odom", "gps_antenna"),)
    d = decide_pose(tf, odo, {"/odom": "nav_msgs/msg/Odometry"}, SENSORS)
    assert d.chosen == "/tf odom->base"
    alone = decide_pose(shape(MOUNTS), odo, {"/odom": "nav_msgs/msg/Odometry"}, SENSORS)
    assert alone.chosen == "/odom" and "gps_antenna is not in the TF tree" in alone.reason


def test_no_common_stamps_is_no_agreement() -> None:
    T = [np.eye(4), np.eye(4)]
    assert agreement_of("/o", "e", ([0, 10**9], T), ([5 * 10**8, 7 * 10**8], T)) is None


def _cloud(topic: str, frame: str, error: str | None = None) -> CloudReport:
    return CloudReport(topic, frame, (), 26, 0, 0, 1, True, False, None, None, (), None, (),
                       Convention("", None, None), error)  # fmt: skip


def test_reference_lidar_and_the_ones_left_out() -> None:
    clouds = [_cloud("/a", "fa"), _cloud("/b", "fb"), _cloud("/e", ""), _cloud("/x", "fx", "bad")]
    counts = {"/a": 10, "/b": 20, "/e": 0, "/x": 30}
    d = decide_lidars(clouds, counts, {"/a": 5.0, "/b": 10.0, "/x": 10.0}, {"fb"})
    assert d.chosen == "/b" and not d.ambiguous
    assert [(c.name, c.usable) for c in d.candidates] == [("/b", True), ("/a", True),
                                                          ("/x", False), ("/e", False)]
    tie = decide_lidars(clouds[:2], {"/a": 20, "/b": 20}, {"/a": 10.0, "/b": 10.0}, set())
    assert tie.chosen == "/a" and tie.ambiguous


def _cam(image_frame: str, info_frame: str) -> CameraReport:
    return CameraReport("/c/image", "sensor_msgs/msg/Image", "/c/info", image_frame, "rgb8", (),
                        (), False, None, info_frame)  # fmt: skip


def test_camera_frame_from_the_tree() -> None:
    d = decide_camera(_cam("cam_optical", "cam"), {"base", "cam"}, {"base", "cam"})
    assert d.chosen == "cam" and not d.ambiguous and "differ" in d.reason
    d = decide_camera(_cam("cam", "cam"), {"cam"}, {"cam"})
    assert d.chosen == "cam" and len(d.candidates) == 1 and not d.ambiguous
    lost = decide_camera(_cam("x", "y"), set(), set())
    assert lost.chosen == "x" and lost.ambiguous


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 12))
def test_relative_motion_with_the_rigid_inverse_equals_the_general_inverse(seed: int,
                                                                          n: int) -> None:
    """`relative_motion` inverts the first pose as a rigid transform (`invert_T`); on random
    poses it agrees with the general matrix inverse it used before to 1e-9 m."""
    rng = np.random.default_rng(seed)
    stamps = np.cumsum(rng.integers(1, 10**8, size=n))
    poses = list(make_T(quat_to_rot(rng.normal(size=(n, 4))), rng.normal(size=(n, 3)) * 100))
    at = [int(s) for s in stamps]
    old = np.stack([(np.linalg.inv(poses[0]) @ T)[:3, 3] for T in poses])
    np.testing.assert_allclose(relative_motion(stamps.tolist(), poses, at), old, rtol=0,
                               atol=1e-9)
