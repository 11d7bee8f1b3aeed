"""pipeline.analysis.geometry_scoring: the poses read at once and the diagonal read on each
view's own map equal the per-view readings they replace, bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from packets.edges import MIN_DEPTH_M, EdgeView, visible
from packets.projection import bilinear, pinhole
from packets.reprojection_consistency import CubicTrack
from packets.rigid import rotated
from pipeline.analysis.align_lidar import BodyTrack
from pipeline.analysis.geometry_scoring import Poses, diagonal, own_maps, score_matrix, view_scores
from schemas.errors import DataError

K = np.array([[80.0, 0, 83.5], [0, 80.0, 55.5], [0, 0, 1]])
HW = (112, 168)


def _poses(seed: int, n: int = 30) -> Poses:
    rng = np.random.default_rng(seed)
    t = 1_700_000_000_000_000_000 + np.cumsum(rng.integers(10**7, 10**8, n))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = rng.normal(size=(n, 3))
    T_cam = np.eye(4)
    T_cam[:3, 3] = [0.1, -0.2, 0.3]
    return Poses.of(BodyTrack(CubicTrack(t, T), {"cam": T_cam}, Path("calibration.parquet")))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10**6), offset_s=st.sampled_from([0.0, -0.05, 0.1]))
def test_sensors_at_equals_sensor_at_per_stamp(seed: int, offset_s: float) -> None:
    body = _poses(seed)
    t = body.track.t
    rng = np.random.default_rng(seed)
    ints = [int(x) for x in rng.integers(t[0] - 10**8, t[-1] + 10**8, 20)]
    moved = [x - offset_s * 1e9 for x in ints]
    # float ns of 1.7e18 round to 256 ns: a float stamp at an end may read past it (Track.at too)
    away = [x for x in moved if min(abs(x - float(t[0])), abs(x - float(t[-1]))) > 1e3]
    for stamps in ([*ints, int(t[0]), int(t[-1])], away):
        got = body.sensors_at("cam", stamps)
        for s, g in zip(stamps, got, strict=True):
            ref = body.sensor_at("cam", s)
            assert (g is None) == (ref is None)
            if ref is not None and g is not None:
                assert np.array_equal(g, ref)


def test_sensors_at_reads_a_cubic_track_stamp_by_stamp_and_names_a_missing_sensor() -> None:
    body = _poses(1)
    cubic = Poses(CubicTrack(body.track.t, body.track.T), body.body)
    stamps = [int(body.track.t[3]) + 12345, int(body.track.t[7]) + 999]
    for g, s in zip(cubic.sensors_at("cam", stamps), stamps, strict=True):
        assert np.array_equal(g, cubic.sensor_at("cam", s))  # type: ignore[arg-type]
    with pytest.raises(DataError, match="no row of sensor 'lidar'"):
        body.sensors_at("lidar", stamps)


def _old_view_scores(v: EdgeView, maps: np.ndarray, r_rad: np.ndarray | None) -> np.ndarray:
    """The per-view score as the stage computed it before `geometry_scoring` (its own
    visibility test and a rotation matrix per view)."""
    h, w, m = maps.shape[:3]
    den = float(np.sum(v.weights))
    pts = v.points if r_rad is None else rotated(v.points, r_rad)
    uv, z = pinhole(pts, v.K)
    inside = (z > MIN_DEPTH_M) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
    inside &= (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5)
    if den <= 0 or not inside.any():
        return np.zeros(m)
    vals = bilinear(maps.reshape(h, w, m * 2), uv[inside]).reshape(-1, m, 2)
    per = np.einsum("nmk,nk->nm", vals, np.abs(v.normals[inside]))
    out: np.ndarray = (v.weights[inside] @ per) / den
    return out


def _views(seed: int, n: int) -> tuple[list[EdgeView], np.ndarray]:
    rng = np.random.default_rng(seed)
    views = []
    for _ in range(n):
        p = int(rng.integers(0, 300))
        pts = np.column_stack([rng.uniform(-6, 6, p), rng.uniform(-4, 4, p), rng.uniform(-1, 9, p)])
        nrm = rng.normal(size=(p, 2))
        views.append(EdgeView(pts, rng.uniform(0, 1, p), nrm, K, np.zeros(HW)))
    return views, rng.normal(size=(*HW, n, 2))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**6), n=st.integers(1, 6), turn=st.booleans())
def test_diagonal_equals_the_per_view_scores(seed: int, n: int, turn: bool) -> None:
    views, maps = _views(seed, n)
    r = np.radians([1.5, -3.0, 0.5]) if turn else None
    ref = np.array([_old_view_scores(v, maps[:, :, i:i + 1], r)[0] for i, v in enumerate(views)])
    assert np.array_equal(diagonal(views, maps, r), ref)
    assert np.array_equal(diagonal(views, own_maps(maps), r), ref)
    full = np.stack([_old_view_scores(v, maps, None) for v in views])
    assert np.array_equal(score_matrix(views, maps), full)
    assert np.array_equal(view_scores(views[0], maps, r), _old_view_scores(views[0], maps, r))


def test_visibility_is_closed_at_the_image_border_and_open_at_min_depth() -> None:
    h, w = HW
    z = 2.0
    uv = np.array([[-0.5, 0.0], [w - 0.5, h - 0.5], [-0.5001, 0.0], [0.0, h - 0.4999]])
    pts = np.column_stack([(uv[:, 0] - K[0, 2]) * z / K[0, 0], (uv[:, 1] - K[1, 2]) * z / K[1, 1],
                           np.full(len(uv), z)])
    pts = np.vstack([pts, [0.0, 0.0, MIN_DEPTH_M], [0.0, 0.0, MIN_DEPTH_M + 1e-9]])
    _, inside = visible(pts, K, HW)
    assert inside.tolist() == [True, True, False, False, False, True]
