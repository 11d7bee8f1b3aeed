"""The reprojection math: closed-form cases, boundaries (behind, outside, ties) and properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.reprojection import (
    G_INV_DEPTH,
    cell_centres,
    cells_to_pixels,
    choose_sources,
    lift,
    packet_depth,
    pixel_to_cell,
    project,
    reproject,
    sample,
    warp_latents,
)
from packets.statistics import CHANNELS
from schemas.packed_cells import VALID_CHANNEL

HW = (28, 42)  # image pixels; grid 2 x 3 cells of 14 px
GRID = (2, 3)
K = np.array([[30.0, 0.0, 20.5], [0.0, 30.0, 13.5], [0.0, 0.0, 1.0]])


def pose(t: tuple[float, float, float] = (0.0, 0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    """T_world_cam with a rotation about the camera's y axis and translation t (m)."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = t
    return T


def latents(S: int, C: int = 4, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(S, C, *GRID))


def test_channel_indices_follow_the_packet_channels() -> None:
    assert CHANNELS[G_INV_DEPTH] == "inv_mean_depth" and CHANNELS[VALID_CHANNEL] == "validity"


def test_packet_depth_reads_inverse_depth_on_valid_cells_only() -> None:
    g = np.zeros((6, *GRID), np.float32)
    g[VALID_CHANNEL, 0, 0], g[G_INV_DEPTH, 0, 0] = 1.0, 0.25
    g[G_INV_DEPTH, 1, 1] = 0.5  # not valid: ignored
    g[VALID_CHANNEL, 1, 2] = 1.0  # valid, zero inverse depth: no support
    d = packet_depth(g)
    assert d[0, 0] == 4.0 and np.count_nonzero(d) == 1


def test_identity_pose_returns_the_source_itself() -> None:
    lat = latents(1)
    depth = np.full(GRID, 7.0)
    for mode in ("nearest", "bilinear"):
        w = warp_latents(lat, depth, K, pose(), K[None], pose()[None], depth[None], HW, mode)
        assert w.valid.all() and (w.source == 0).all()
        np.testing.assert_allclose(w.latent, lat[0], atol=1e-12)


def test_translation_on_a_fronto_parallel_plane_shifts_by_one_cell() -> None:
    Z, sx = 5.0, HW[1] / GRID[1]
    T_src = pose((sx * Z / K[0, 0], 0.0, 0.0))  # source moved right: content moves left sx px
    rep = reproject(np.full(GRID, Z), K, pose(), K[None], T_src[None], HW)
    want_cols = np.arange(GRID[1]) - 1.0
    np.testing.assert_allclose(rep.cell[0, ..., 1], np.broadcast_to(want_cols, GRID), atol=1e-9)
    np.testing.assert_allclose(rep.cell[0, ..., 0], [[0, 0, 0], [1, 1, 1]], atol=1e-9)
    assert (rep.inside[0] == [[False, True, True]] * 2).all()  # column 0 falls off the left
    lat = latents(1)
    w = warp_latents(lat, np.full(GRID, Z), K, pose(), K[None], T_src[None],
                     np.full((1, *GRID), Z), HW)
    np.testing.assert_allclose(w.latent[:, :, 1:], lat[0][:, :, :-1], atol=1e-12)
    assert (w.latent[:, :, 0] == 0).all() and not w.valid[:, 0].any()


def test_points_behind_the_source_camera_are_dropped() -> None:
    rep = reproject(np.full(GRID, 3.0), K, pose(), K[None], pose(yaw=np.pi)[None], HW)
    assert not rep.inside.any() and (rep.depth < 0).all()


def test_point_on_the_camera_plane_is_not_inside() -> None:
    # the source sits at the plane's depth: every point has z = 0 there
    rep = reproject(np.full(GRID, 3.0), K, pose(), K[None], pose((0.0, 0.0, 3.0))[None], HW)
    assert not rep.inside.any()


def test_image_edges_are_inside_and_beyond_is_outside() -> None:
    uv = np.array([[-0.5, -0.5], [41.5, 27.5], [-0.5 - 1e-9, 3.0], [3.0, 27.5 + 1e-9]])
    from packets.projection import in_image
    assert in_image(uv, HW).tolist() == [True, True, False, False]
    np.testing.assert_allclose(pixel_to_cell(uv[:2], GRID, HW), [[-0.5, -0.5], [1.5, 2.5]])


def test_unsupported_cells_stay_invalid() -> None:
    depth = np.full(GRID, 4.0)
    depth[0, 1], depth[1, 2] = 0.0, np.nan
    w = warp_latents(latents(1), depth, K, pose(), K[None], pose()[None], depth[None], HW)
    assert w.valid.tolist() == [[True, False, True], [True, True, False]]
    assert (w.source[~w.valid] == -1).all()


def test_ties_in_depth_go_to_the_lowest_source_index() -> None:
    depth = np.full(GRID, 4.0)
    rep = reproject(depth, K, pose(), np.stack([K, K]), np.stack([pose(), pose()]), HW)
    assert (choose_sources(rep, np.stack([depth, depth])) == 0).all()


def test_nearer_source_wins_among_equals() -> None:
    depth = np.full(GRID, 10.0)
    Ts = np.stack([pose((0.0, 0.0, -2.0)), pose((0.0, 0.0, 2.0))])  # source 1 nearer the plane
    rep = reproject(depth, K, pose(), np.stack([K, K]), Ts, HW)
    src_d = np.stack([np.full(GRID, 12.0), np.full(GRID, 8.0)])  # both confirm
    assert (choose_sources(rep, src_d) == 1).all()


def test_occluded_source_is_dropped_and_confirmed_source_preferred() -> None:
    depth = np.full(GRID, 10.0)
    rep = reproject(depth, K, pose(), np.stack([K, K, K]), np.stack([pose()] * 3), HW)
    occluder = np.full(GRID, 5.0)  # source 0 sees something in front of the point
    unknown = np.zeros(GRID)  # source 1 has no LiDAR there
    confirms = np.full(GRID, 10.5)  # source 2 agrees within 10 %
    assert (choose_sources(rep, np.stack([occluder, unknown, confirms])) == 2).all()
    assert (choose_sources(rep, np.stack([occluder, unknown, unknown])) == 1).all()
    assert (choose_sources(rep, np.stack([occluder, occluder, occluder])) == -1).all()


def test_visibility_tolerance_is_inclusive() -> None:
    depth = np.full(GRID, 10.0)
    rep = reproject(depth, K, pose(), K[None], pose()[None], HW)
    at_edge = np.full((1, *GRID), 9.0)  # exactly rel_tol in front: not occluded, confirmed
    assert (choose_sources(rep, at_edge, rel_tol=0.1) == 0).all()
    assert (choose_sources(rep, np.full((1, *GRID), 8.9), rel_tol=0.1) == -1).all()


def test_bilinear_interpolates_between_cells_and_clamps_at_edges() -> None:
    lat = np.arange(6, dtype=np.float64).reshape(1, 2, 3)
    got = sample(lat, np.array([[0.5, 0.5], [-3.0, 9.0], [1.0, 2.0]]), "bilinear")
    np.testing.assert_allclose(got[0], [2.0, 2.0, 5.0])
    np.testing.assert_allclose(sample(lat, np.array([[0.49, 1.5]]), "nearest")[0], [2.0])
    with pytest.raises(ValueError, match="sampling"):
        sample(lat, np.zeros((1, 2)), "cubic")  # type: ignore[arg-type]


def test_cells_to_pixels_expands_each_cell_over_its_patch() -> None:
    m = np.array([[True, False, False], [False, False, True]])
    px = cells_to_pixels(m, HW)
    assert px.shape == HW and px[:14, :14].all() and not px[:14, 14:].any()
    assert px[14:, 28:].all() and px.sum() == 2 * 14 * 14


finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(t=st.tuples(finite, finite, finite), yaw=st.floats(-np.pi, np.pi),
       z=st.floats(1e-2, 1e4))
def test_lift_then_project_into_the_same_camera_returns_the_cell_centres(
        t: tuple[float, float, float], yaw: float, z: float) -> None:
    T = pose(t, yaw)
    uv, depth = project(lift(np.full(GRID, z), K, T, HW), K, T)
    np.testing.assert_allclose(uv, cell_centres(GRID, HW), atol=1e-6 * max(1.0, z / 10))
    np.testing.assert_allclose(depth, z, rtol=1e-9)


@settings(max_examples=60, deadline=None)
@given(t=st.tuples(finite, finite, finite), yaw=st.floats(-np.pi, np.pi),
       z=st.floats(1e-2, 1e4), seed=st.integers(0, 2**16))
def test_warp_reads_only_source_values_and_is_invariant_to_a_world_transform(
        t: tuple[float, float, float], yaw: float, z: float, seed: int) -> None:
    """Moving every camera by one rigid world transform changes nothing; nearest sampling
    copies source latents (never invents values)."""
    rng = np.random.default_rng(seed)
    lat = latents(2, seed=seed)
    depth = np.where(rng.random(GRID) < 0.8, z, 0.0)
    T_src = np.stack([pose(tuple(rng.normal(size=3) * 0.1 * z), rng.normal() * 0.1),
                      pose(tuple(rng.normal(size=3) * 0.1 * z))])
    W = pose(t, yaw)
    a = warp_latents(lat, depth, K, pose(), np.stack([K, K]), T_src, np.zeros((2, *GRID)), HW)
    b = warp_latents(lat, depth, K, W, np.stack([K, K]), W @ T_src, np.zeros((2, *GRID)), HW)
    np.testing.assert_allclose(a.latent, b.latent, atol=1e-9)
    assert not (a.valid & (depth == 0)).any()
    pool = lat.transpose(0, 2, 3, 1).reshape(-1, lat.shape[1])
    for v in a.latent.transpose(1, 2, 0)[a.valid]:
        assert np.isclose(pool, v).all(axis=1).any()
