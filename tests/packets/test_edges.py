"""LiDAR edge points on their own: the scan-neighbour edge points of a synthetic sweep, and
their alignment score on a scene whose image edges are known exactly (no rendering, no I/O;
the band-passed edge map and the rotation search: tests/pipeline/analysis/test_edge_align.py)."""

from __future__ import annotations

import numpy as np
import pytest

from packets.edges import (
    EdgeView,
    ScanEdges,
    alignment_score,
    camera_edges,
    edge_sums,
    scan_candidates,
    scan_edges,
    scan_edges_and_step,
    scan_neighbours,
    visible,
)
from packets.rigid import rotated as rotated_pts

K = np.array([[60.0, 0.0, 79.5], [0.0, 60.0, 59.5], [0.0, 0.0, 1.0]])
HW = (120, 160)


def ring_sweep(step_az_deg: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A 32-ring sweep (z up, x forward) of a wall 10 m ahead with a box 4 m ahead covering
    azimuths -10..10 deg and elevations below +5 deg; intensity 100 on the wall, 200 on the box."""
    az = np.radians(np.arange(-60, 60, step_az_deg))
    el = np.radians(np.arange(-16.0, 16.0, 1.0))
    A, E = np.meshgrid(az, el, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    box = (np.abs(A) <= np.radians(10)).ravel() & (np.radians(5) >= E).ravel()
    rng = np.where(box, 4.0, 10.0) / d[:, 0]  # planes x = 4 and x = 10
    return d * rng[:, None], np.where(box, 200.0, 100.0)


def test_scan_edges_sit_between_neighbours_on_the_near_surface() -> None:
    xyz, inten = ring_sweep()
    edges = scan_edges(xyz, inten)
    assert len(edges.points) > 0 and (edges.weights > 0).all() and (edges.weights <= 1).all()
    az = np.degrees(np.arctan2(edges.points[:, 1], edges.points[:, 0]))
    el = np.degrees(np.arcsin(edges.points[:, 2] / np.linalg.norm(edges.points, axis=1)))
    top = np.abs(el - 5.5) < 0.1  # its top: midway between rings 5 and 6
    side = (np.abs(np.abs(az) - 10.0) < 0.5) & ~top  # its sides: midway between columns
    assert (side | top).all() and side.any() and top.any()
    np.testing.assert_allclose(np.abs(az[side]), 10.25, atol=0.01)
    np.testing.assert_allclose(edges.points[:, 0], 4.0, rtol=1e-3)  # at the nearer range
    a = np.radians(az[side])
    tangent = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)], 1)  # along azimuth
    np.testing.assert_allclose(np.abs(np.sum(edges.across[side] * tangent, 1)), 1.0, atol=0.01)


def test_a_smooth_grazing_surface_has_no_edges() -> None:
    az = np.radians(np.arange(-60, 60, 0.5))
    el = np.radians(np.arange(-16.0, -1.0, 1.0))
    A, E = np.meshgrid(az, el, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    ground = d * (-0.5 / d[:, 2])[:, None]  # the plane z = -0.5 seen at grazing angles
    assert len(scan_edges(ground).points) == 0
    assert len(scan_edges(np.zeros((3, 3))).points) == 0


def box_image(r_true: np.ndarray) -> tuple[ScanEdges, np.ndarray]:
    """Edges of `ring_sweep` and the image of its box silhouette seen by a camera turned by
    r_true (pixels whose ray, turned, hits the box are bright), at 4x supersampling. One sweep
    places an edge only within its scan spacing (the method is unbiased over many sweeps of
    different phase), so the drawn box ends where the sweep's midpoints put it: +-10.25 deg
    azimuth (columns every 0.5 deg), 5.5 deg elevation (rings every 1 deg)."""
    from scipy.spatial.transform import Rotation

    xyz, inten = ring_sweep(0.5)
    R = Rotation.from_rotvec(r_true).as_matrix()
    s = 4
    v, u = np.mgrid[0:HW[0] * s, 0:HW[1] * s]
    pix = np.stack([(u + 0.5) / s - 0.5, (v + 0.5) / s - 0.5, np.ones_like(u, float)], -1)
    rays = (pix @ np.linalg.inv(K).T) @ R.T  # true camera's rays, in the nominal camera frame
    x, y = rays[..., 0] / rays[..., 2], rays[..., 1] / rays[..., 2]  # on the plane z_cam = 1
    # nominal camera: z forward = lidar x, x right = -lidar y, y down = -lidar z
    box = (np.abs(x) <= np.tan(np.radians(10.25))) & (
        -y <= np.tan(np.radians(5.5)) / np.cos(np.arctan(x)))
    img = box.reshape(HW[0], s, HW[1], s).mean((1, 3)) * 200.0
    return scan_edges(xyz, inten), img


T_CAM_LIDAR = np.array([[0.0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])


def test_the_score_peaks_at_the_true_rotation_on_a_plain_gradient_map() -> None:
    r_true = np.radians([0.4, -0.6, 0.5])
    edges, img = box_image(r_true)
    view = camera_edges(edges, T_CAM_LIDAR, K, img)
    assert len(view.points) > 20 and (np.linalg.norm(view.normals, axis=1) > 0.99).all()
    maps = [np.stack([np.abs(np.gradient(img, axis=1)), np.abs(np.gradient(img, axis=0))], -1)]
    at_true = alignment_score([view], maps, r_true)
    assert at_true > alignment_score([view], maps, r_true + 0.02)
    assert at_true > alignment_score([view], maps, np.zeros(3))


def _sum_of_points_score(views: list[EdgeView], maps: list[np.ndarray], r: np.ndarray) -> float:
    """The score as `alignment_score` summed it before `edge_sums`: every point, 0 outside."""
    from packets.projection import bilinear
    from packets.rigid import rotated

    num = den = 0.0
    for v, m in zip(views, maps, strict=True):
        uv, inside = visible(rotated(v.points, r), v.K, (m.shape[0], m.shape[1]))
        vals = np.zeros(len(uv))
        vals[inside] = np.sum(bilinear(m, uv[inside]) * np.abs(v.normals[inside]), axis=1)
        num += float(np.sum(v.weights * vals))
        den += float(np.sum(v.weights))
    return num / den if den > 0 else float("nan")


def test_alignment_score_is_the_weighted_mean_of_edge_sums_over_views() -> None:
    rng = np.random.default_rng(7)
    views, maps = [], []
    for p in (0, 40, 250):
        pts = np.column_stack([rng.uniform(-6, 6, p), rng.uniform(-4, 4, p), rng.uniform(-1, 9, p)])
        views.append(EdgeView(pts, rng.uniform(0, 1, p), rng.normal(size=(p, 2)), K,
                              np.zeros(HW)))
        maps.append(rng.normal(size=(*HW, 2)))
    for r in (np.zeros(3), np.radians([1.0, -2.0, 0.5])):
        got = alignment_score(views, maps, r)
        np.testing.assert_allclose(got, _sum_of_points_score(views, maps, r), rtol=1e-13)
        num = sum(edge_sums(v, rotated_pts(v.points, r), m[:, :, None, :])[0][0]
                  for v, m in zip(views, maps, strict=True))
        np.testing.assert_allclose(got, num / sum(float(v.weights.sum()) for v in views),
                                   rtol=1e-13)
    empty = EdgeView(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2)), K, np.zeros(HW))
    assert np.isnan(alignment_score([empty], [maps[0]], np.zeros(3)))


def test_scan_neighbours_from_shared_candidates_equal_their_own_query() -> None:
    """The ring candidates queried once (`scan_candidates`) give every gap's neighbours as the
    query `scan_neighbours` makes on its own, bit for bit."""
    xyz, _ = ring_sweep()
    p = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    key = np.stack([np.arctan2(p[:, 1], p[:, 0]), np.arcsin(p[:, 2])], 1)
    for along in (0, 1):
        cand = scan_candidates(key, along)
        for gap in (np.radians(3.0), np.radians(20.0)):
            assert np.array_equal(scan_neighbours(key, along, gap, cand),
                                  scan_neighbours(key, along, gap))


def test_scan_edges_and_step_share_one_ring_query_and_change_nothing() -> None:
    rng = np.random.default_rng(7)
    for step in (0.5, 1.3):
        xyz, inten = ring_sweep(step)
        xyz = xyz + rng.normal(0, 1e-3, xyz.shape)
        xyz[::97] = np.nan  # no return
        xyz[5::89] = 0.0
        for i in (inten, None):
            edges, got = scan_edges_and_step(xyz, i)
            ref = scan_edges(xyz, i)
            for a, b in zip((edges.points, edges.weights, edges.across),
                            (ref.points, ref.weights, ref.across), strict=True):
                assert np.array_equal(a, b)
            assert got == pytest.approx(np.radians(step), rel=0.05)
    few, step0 = scan_edges_and_step(np.ones((4, 3)))
    assert len(few.points) == 0 and step0 == 0.0
