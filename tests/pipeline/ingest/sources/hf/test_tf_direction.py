"""The `tf` direction choice on a rig whose answer is known; the other choice fails it.

Rig (written by hand in the release's convention, not by our writer): `box_base` sits 0.5 m
above `base`, unrotated; `hdr_front` is 0.3 m ahead of `box_base` (+x), looking forward (optical
z along +x, optical x along -y, optical y along -z). A `tf` entry maps parent coordinates into
the child frame, so hdr_front's entry is T_cam_box = [R^T | -R^T c] with R the optical axes in
box_base and c = (0.3, 0, 0): translation (0, 0, -0.3), rotation R^T = [[0,-1,0],[0,0,-1],[1,0,0]],
i.e. quaternion w 0.5, x 0.5, y -0.5, z 0.5 (worked out by hand from the trace formula).
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.sources.hf.calib import tf_tree

RIG = {
    "box_base": {"translation": {"x": 0.0, "y": 0.0, "z": -0.5},
                 "rotation": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0}, "base_frame_id": "base"},
    "hdr_front": {"translation": {"x": 0.0, "y": 0.0, "z": -0.3},
                  "rotation": {"w": 0.5, "x": 0.5, "y": -0.5, "z": 0.5},
                  "base_frame_id": "box_base"},
}  # fmt: skip


def check_rig(tree: TfTree) -> None:
    """The known answer: camera 0.3 m ahead and 0.5 m up, looking along base +x."""
    T = tree.lookup("base", "hdr_front")  # T_base_cam
    np.testing.assert_allclose(T[:3, 3], [0.3, 0.0, 0.5], atol=1e-12)  # optical centre
    np.testing.assert_allclose(T[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)  # optical axis: forward
    np.testing.assert_allclose(T[:3, 1], [0.0, 0.0, -1.0], atol=1e-12)  # image down: down
    ahead = T @ np.array([0.0, 0.0, 4.7, 1.0])  # 4.7 m along the optical axis
    np.testing.assert_allclose(ahead[:3], [5.0, 0.0, 0.5], atol=1e-12)


def test_chosen_direction_gives_the_known_rig() -> None:
    tree, rejects = tf_tree(RIG, "child_from_parent", "data/tf")
    assert rejects == []
    check_rig(tree)


def test_the_other_direction_fails_the_rig() -> None:
    tree, _ = tf_tree(RIG, "parent_from_child", "data/tf")
    with pytest.raises(AssertionError):
        check_rig(tree)


def test_default_config_uses_the_chosen_direction() -> None:
    from schemas.config import HfConfig

    check_rig(tf_tree(RIG, HfConfig().tf_direction, "data/tf")[0])


def test_bad_entry_is_a_reject_naming_it() -> None:
    bad = {**RIG, "hesai_lidar": {"translation": {"x": 0.0}, "base_frame_id": "box_base"}}
    tree, rejects = tf_tree(bad, "child_from_parent", "data/tf")
    assert len(rejects) == 1 and "'hesai_lidar'" in rejects[0].detail
    check_rig(tree)
