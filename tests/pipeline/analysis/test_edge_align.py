"""The edge maps and the rotation search of the LiDAR edge alignment: the band-passed edge map
of a step, and the rotation recovered from a scene whose image edges are known exactly (the
scene: tests/packets/test_edges.py)."""

from __future__ import annotations

import numpy as np
import pytest

from packets.edges import EdgeView, alignment_score, camera_edges
from pipeline.analysis.edge_align import align_rotation, edge_map
from tests.packets.test_edges import HW, T_CAM_LIDAR, K, box_image


def test_edge_map_is_band_passed_and_zero_for_a_flat_image() -> None:
    img = np.zeros(HW)
    img[:, 80:] = 100.0
    m = edge_map(img, 1.0)
    assert m.shape == (*HW, 2)
    assert m[60, 79:81, 0].min() > 0 and abs(m[60, 40, 0]) < 1e-9  # u edge at the step
    assert np.abs(m[..., 1]).max() < 1e-9  # no v gradient
    assert not edge_map(np.full(HW, 7.0), 1.0).any()


@pytest.mark.parametrize("r_deg", [(0.0, 0.0, 0.0), (0.4, -0.6, 0.5)])
def test_align_rotation_recovers_a_turned_camera(r_deg: tuple[float, float, float]) -> None:
    r_true = np.radians(r_deg)
    edges, img = box_image(r_true)
    view = camera_edges(edges, T_CAM_LIDAR, K, img)
    assert isinstance(view, EdgeView) and len(view.points) > 20
    est = align_rotation([view], np.radians(1.5))
    # one view of one centred box: its corners bend the band-passed map, and its edges pass
    # near the optical axis, so roll is weakly held (the recordings' many views resolve it:
    # tests/pipeline/analysis/test_align_consistency.py); pitch and yaw are held here
    assert np.degrees(np.abs(np.asarray(est.rotation_rad) - r_true))[:2].max() < 0.3, est
    assert est.score_max >= est.score_nominal
    maps = [edge_map(img, 1.0)]
    assert alignment_score([view], maps, r_true) > alignment_score([view], maps, r_true + 0.02)
