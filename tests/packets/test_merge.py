"""Several LiDARs in one packet: points carried by their own transforms, per-point delta tau
pooled per cell (exact on cells one sweep supports), features stacked in the same order."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.assemble import build_packet, packet_from_support, view_support
from packets.merge import SweepPart, cell_delta_tau, merge_in_camera
from packets.poses import make_T, quat_to_rot
from packets.statistics import cell_depth_stats, explicit_channels
from packets.support import SupportSets
from schemas.channels import DELTA_TAU, VALIDITY, channel_index
from schemas.errors import DataError

K = np.array([[60.0, 0.0, 83.5], [0.0, 60.0, 55.5], [0.0, 0.0, 1.0]])
HW = (112, 168)


def _cloud(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) float32 points 2-12 m in front of an identity camera."""
    z = rng.uniform(2.0, 12.0, n)
    x, y = rng.uniform(-0.7, 0.7, n) * z, rng.uniform(-0.5, 0.5, n) * z
    return np.stack([x, y, z], 1).astype(np.float32)


def test_points_land_in_the_camera_through_their_own_transforms() -> None:
    rng = np.random.default_rng(0)
    a, b = _cloud(rng, 50), _cloud(rng, 30)
    Ta = make_T(quat_to_rot([0.0, 0.0, np.sin(0.2), np.cos(0.2)]), [0.1, 0.0, -0.3])
    Tb = make_T(quat_to_rot([np.sin(0.1), 0.0, 0.0, np.cos(0.1)]), [-0.2, 0.05, 0.4])
    m = merge_in_camera([SweepPart(a, Ta, 0.01), SweepPart(b, Tb, -0.04)])
    assert m.sizes == (50, 30) and m.xyz_cam.dtype == np.float64 and m.features is None
    want = np.concatenate([a @ Ta[:3, :3].T + Ta[:3, 3], b @ Tb[:3, :3].T + Tb[:3, 3]])
    np.testing.assert_allclose(m.xyz_cam, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(m.delta_tau_s, np.r_[np.full(50, 0.01), np.full(30, -0.04)])


def test_features_are_stacked_in_part_order_and_must_all_be_there() -> None:
    rng = np.random.default_rng(1)
    a, b = _cloud(rng, 4), _cloud(rng, 3)
    fa, fb = np.ones((4, 2), np.float32), np.full((3, 2), 2.0, np.float32)
    m = merge_in_camera([SweepPart(a, np.eye(4), 0.0, fa), SweepPart(b, np.eye(4), 0.0, fb)])
    assert m.features is not None
    np.testing.assert_array_equal(np.asarray(m.features), np.r_[fa, fb])
    t = merge_in_camera([SweepPart(a, np.eye(4), 0.0, torch.from_numpy(fa)),
                         SweepPart(b, np.eye(4), 0.0, torch.from_numpy(fb))])
    assert isinstance(t.features, torch.Tensor) and t.features.shape == (7, 2)
    with pytest.raises(DataError, match="some sweeps have point features"):
        merge_in_camera([SweepPart(a, np.eye(4), 0.0, fa), SweepPart(b, np.eye(4), 0.0)])
    with pytest.raises(DataError, match="widths"):
        merge_in_camera([SweepPart(a, np.eye(4), 0.0, fa),
                         SweepPart(b, np.eye(4), 0.0, np.ones((3, 5), np.float32))])
    with pytest.raises(DataError, match="3 rows for a sweep of 4"):
        merge_in_camera([SweepPart(a, np.eye(4), 0.0, fb), SweepPart(b, np.eye(4), 0.0, fb)])


def test_bad_parts_are_refused_by_name() -> None:
    with pytest.raises(DataError, match="at least one"):
        merge_in_camera([])
    with pytest.raises(DataError, match="sweep 1 of the merge"):
        merge_in_camera([SweepPart(np.zeros((2, 3)), np.eye(4), 0.0),
                         SweepPart(np.zeros((2, 2)), np.eye(4), 0.0)])
    bad_T = np.eye(4)
    bad_T[0, 3] = np.nan
    with pytest.raises(DataError, match="T_cam_lidar of sweep 0"):
        merge_in_camera([SweepPart(np.zeros((2, 3)), bad_T, 0.0)])
    with pytest.raises(DataError, match="delta_tau_s of sweep 0"):
        merge_in_camera([SweepPart(np.zeros((2, 3)), np.eye(4), float("inf"))])


def test_one_value_per_point_equal_everywhere_gives_the_views_packet_exactly() -> None:
    """A per-point delta tau that is the same for every point is the single-LiDAR packet, to
    the bit (the shifted mean is exact on constant cells)."""
    rng = np.random.default_rng(2)
    xyz = _cloud(rng, 400)
    sup = view_support(xyz, K, np.eye(4), HW)
    for dt in (0.1, -0.0371, 1e-9, 7.3):
        one = packet_from_support(sup, dt, None, mode="geom_only", front_margin_m=0.5)
        per = packet_from_support(sup, np.full(400, dt), None, mode="geom_only",
                                  front_margin_m=0.5)
        assert one.g is not None and per.g is not None
        assert np.array_equal(one.g, per.g)


def test_a_cell_takes_the_mean_delta_tau_of_the_points_it_pools() -> None:
    cell = np.array([0, 0, 0, 1, 2, 2], np.int64)
    sup = SupportSets(point_idx=np.array([5, 0, 1, 2, 3, 4], np.int64), cell=cell,
                      depth=np.ones(6), grid_hw=(2, 2), n_points=6)
    point_dt = np.array([0.03, -0.02, 0.05, 0.05, 0.01, 0.07])
    got = cell_delta_tau(sup, point_dt)
    np.testing.assert_allclose(got, [(0.07 + 0.03 - 0.02) / 3, 0.05, (0.05 + 0.01) / 2, 0.0])
    g = explicit_channels(cell_depth_stats(cell, np.full(6, 4.0), 4), got, (2, 2))
    dt, v = channel_index(DELTA_TAU), channel_index(VALIDITY)
    assert g[v].ravel().tolist() == [1.0, 1.0, 1.0, 0.0] and g[dt, 1, 1] == 0.0
    with pytest.raises(DataError, match="point delta tau"):
        cell_delta_tau(sup, point_dt[:5])
    with pytest.raises(DataError, match="per-cell delta tau has shape"):
        explicit_channels(cell_depth_stats(cell, np.full(6, 4.0), 4), got[:3], (2, 2))


def test_front_surface_pools_delta_tau_over_the_points_it_keeps() -> None:
    """Two LiDARs see one cell at 5 m and 9 m: with a 0.5 m front margin the cell keeps only
    the near sweep's points and so exactly its delta tau."""
    near = np.array([[0.0, 0.0, 5.0], [0.01, 0.0, 5.0]], np.float32)
    far = np.array([[0.0, 0.01, 9.0]], np.float32)
    m = merge_in_camera([SweepPart(near, np.eye(4), -0.03), SweepPart(far, np.eye(4), 0.02)])
    pkt = build_packet(m.xyz_cam, K, np.eye(4), HW, 0.0, None, mode="geom_only")
    sup = view_support(m.xyz_cam, K, np.eye(4), HW)
    kept = packet_from_support(sup, m.delta_tau_s, None, mode="geom_only", front_margin_m=0.5)
    pooled = packet_from_support(sup, m.delta_tau_s, None, mode="geom_only")
    occ = pkt.g[channel_index(VALIDITY)] > 0
    dt = channel_index(DELTA_TAU)
    assert occ.sum() == 1 and kept.g is not None and pooled.g is not None
    assert kept.g[dt][occ][0] == np.float32(-0.03)
    assert pooled.g[dt][occ][0] == np.float32((-0.03 - 0.03 + 0.02) / 3)


@settings(max_examples=60, deadline=None)
@given(values=st.lists(st.floats(-10.0, 10.0, allow_nan=False, width=64), min_size=1,
                       max_size=40),
       cells=st.lists(st.integers(0, 3), min_size=40, max_size=40))
def test_cell_delta_tau_lies_between_its_points_extremes(values: list[float],
                                                          cells: list[int]) -> None:
    n = len(values)
    cell = np.asarray(cells[:n], np.int64)
    d = np.asarray(values)
    sup = SupportSets(point_idx=np.arange(n, dtype=np.int64), cell=cell, depth=np.ones(n),
                      grid_hw=(2, 2), n_points=n)
    got = cell_delta_tau(sup, d)
    for c in range(4):
        here = d[cell == c]
        if here.size == 0:
            assert got[c] == 0.0
        else:
            assert here.min() <= got[c] <= here.max()
            if np.all(here == here[0]):
                assert got[c] == here[0]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), sizes=st.lists(st.integers(0, 300), min_size=1, max_size=4))
def test_merge_carries_points_as_the_inline_transform_did(seed: int, sizes: list[int]) -> None:
    """Each sweep's points land where `pts @ R^T + t` (the arithmetic merge wrote inline
    before it called `packets.rigid.apply_T`) puts them, bit for bit."""
    rng = np.random.default_rng(seed)
    parts = [SweepPart(rng.normal(size=(n, 3)) * 20,
                       make_T(quat_to_rot(rng.normal(size=4)), rng.normal(size=3)), 0.0)
             for n in sizes]
    old = np.concatenate([np.asarray(p.xyz) @ np.asarray(p.T_cam_lidar)[:3, :3].T
                          + np.asarray(p.T_cam_lidar)[:3, 3] for p in parts])
    assert np.array_equal(merge_in_camera(parts).xyz_cam, old)
