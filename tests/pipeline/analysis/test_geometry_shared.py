"""pipeline.analysis.geometry_views and geometry_overlap: what the stage now computes once and
shares (the first sweep's ring query for the azimuth step, the LiDAR poses read at once, the
near pairs scored together) equals what it computed one by one, bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from packets.edges import camera_edges, scan_edges, scan_edges_and_step
from packets.reprojection_consistency import Track
from packets.view_overlap import near_pairs
from pipeline.analysis.align_lidar import BodyTrack
from pipeline.analysis.geometry_overlap import cross_arrays
from pipeline.analysis.geometry_scoring import CameraSet, Poses, RawView, view_scores
from pipeline.analysis.geometry_views import _lidar_poses, azimuth_step
from tests.packets.test_edges import ring_sweep

K = np.array([[80.0, 0, 83.5], [0, 80.0, 55.5], [0, 0, 1]])
HW = (112, 168)
T0 = 1_700_000_000_000_000_000


def _body(seed: int, n: int = 40) -> Poses:
    rng = np.random.default_rng(seed)
    t = T0 + np.cumsum(rng.integers(10**7, 5 * 10**7, n))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.02, (n, 3)).cumsum(0)).as_matrix()
    T[:, :3, 3] = rng.normal(0, 0.05, (n, 3)).cumsum(0)
    cam, lid = np.eye(4), np.eye(4)
    cam[:3, :3] = Rotation.from_euler("xyz", [-90, 0, -90], degrees=True).as_matrix()
    lid[:3, 3] = [0.1, 0.0, 0.3]
    return Poses.of(BodyTrack(Track(t, T), {"cam": cam, "lidar": lid, "lidar2": lid @ cam},
                              Path("calibration.parquet")))


def test_the_first_sweeps_shared_ring_query_gives_azimuth_step_bit_for_bit() -> None:
    rng = np.random.default_rng(2)
    for step in (0.2, 0.5, 2.0):
        xyz, inten = ring_sweep(step)
        xyz = (xyz + rng.normal(0, 1e-3, xyz.shape)).astype(np.float32)  # as sweeps decode
        xyz[::53] = np.nan
        edges, got = scan_edges_and_step(xyz, inten)
        assert got == azimuth_step(xyz)
        assert np.array_equal(edges.points, scan_edges(xyz, inten).points)


def test_lidar_poses_read_at_once_equal_sensor_at_per_row() -> None:
    body = _body(3)
    t = body.track.t
    rng = np.random.default_rng(3)
    stamps = [int(x) for x in rng.integers(t[0] - 10**8, t[-1] + 10**8, 30)]
    sweeps = {k: {"lidar": "lidar" if k % 3 else "lidar2"} for k in range(30)}
    rows = [{"sweep": k, "sweep_stamp_ns": s} for k, s in enumerate(stamps)]
    got = _lidar_poses(body, rows, sweeps)
    for r, g in zip(rows, got, strict=True):
        ref = body.sensor_at(sweeps[r["sweep"]]["lidar"], r["sweep_stamp_ns"])
        assert (g is None) == (ref is None)
        assert g is None or np.array_equal(g, ref)  # type: ignore[arg-type]


def _old_cross_arrays(cs: CameraSet, body: Poses, scored: list[int], maps: np.ndarray,
                      max_lag: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cross_arrays as the stage computed it pair by pair."""
    views = [cs.views[k] for k in scored]
    T_cam = [np.eye(4) if T is None else T
             for T in body.sensors_at(cs.camera, [v.image_ns for v in views])]
    pairs = near_pairs(len(views), max_lag)
    scores, points = np.zeros(len(pairs)), np.zeros(len(pairs), np.int64)
    for p, (i, j) in enumerate(pairs):
        T = np.asarray(np.linalg.solve(T_cam[j], views[i].T_odom_lidar), np.float64)
        ev = camera_edges(views[i].edges, T, views[j].K, views[j].grey)
        points[p] = len(ev.points)
        scores[p] = view_scores(ev, maps[:, :, j:j + 1])[0] if len(ev.points) else 0.0
    return scores, points, pairs


def test_near_pairs_scored_together_equal_the_pair_by_pair_scores() -> None:
    body = _body(5)
    t = body.track.t
    rng = np.random.default_rng(5)
    xyz, inten = ring_sweep(0.5)
    edges = scan_edges(xyz, inten)
    views = []
    for k in range(9):
        stamp = int(t[3 + 3 * k])
        T_l = body.sensor_at("lidar", stamp)
        assert T_l is not None
        views.append(RawView(edges, T_l, stamp + int(rng.integers(0, 10**7)), K,
                             np.zeros(HW), stamp))
    cs = CameraSet("cam", views, len(views), 0)
    scored = [0, 1, 2, 4, 5, 7, 8]
    maps = rng.normal(size=(*HW, len(scored), 2))
    for lag in (1, 3, 6):
        got = cross_arrays(cs, body, scored, maps, lag)
        ref = _old_cross_arrays(cs, body, scored, maps, lag)
        for a, b in zip(got, ref, strict=True):
            assert np.array_equal(a, b)
    assert (got[1] > 0).any() and (got[0] != 0).any()  # pairs see common points: not trivial
