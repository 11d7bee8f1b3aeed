"""packets.edge_batch: the views scored together on their own maps equal the per-view scores
(`pipeline.analysis.geometry_scoring.diagonal`, `packets.edges.edge_sums`) bit for bit, for
the nominal points, every rotation and shift the geometry check's cause search tries, views of
0 and 1 points, zero weights, points behind the camera and views of different K."""

from __future__ import annotations

import dataclasses

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.edge_batch import EdgeBatch, camera_edges_many, own_scores, rows_product
from packets.edges import EdgeView, ScanEdges, camera_edges
from packets.rigid import rotvec_matrix
from pipeline.analysis.geometry_scoring import diagonal

HW = (112, 168)


def _K(f: float) -> np.ndarray:
    return np.array([[f, 0, 83.5], [0, f, 55.5], [0, 0, 1]])


def _views(seed: int, n: int, same_k: bool) -> tuple[list[EdgeView], np.ndarray]:
    rng = np.random.default_rng(seed)
    views = []
    for i in range(n):
        p = int(rng.choice([0, 1, 2, int(rng.integers(3, 400))]))
        pts = np.column_stack([rng.uniform(-6, 6, p), rng.uniform(-4, 4, p),
                               rng.uniform(-1, 9, p)])
        w = rng.uniform(0, 1, p) if i % 5 else np.zeros(p)
        k = _K(80.0) if same_k else _K(float(rng.uniform(60, 120)))
        views.append(EdgeView(pts, w, rng.normal(size=(p, 2)), k, np.zeros(HW)))
    return views, rng.normal(size=(*HW, n, 2))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10**6), n=st.integers(1, 12), same_k=st.booleans())
def test_own_scores_equal_the_per_view_diagonal(seed: int, n: int, same_k: bool) -> None:
    views, maps = _views(seed, n, same_k)
    batch = EdgeBatch.of(views)
    assert np.array_equal(own_scores(batch, batch.points, maps), diagonal(views, maps))
    for axis in range(3):
        for deg in (-8.0, -2.0, 3.0, 5.0):
            r = np.zeros(3)
            r[axis] = np.radians(deg)
            got = own_scores(batch, batch.rotated(rotvec_matrix(r)), maps)
            assert np.array_equal(got, diagonal(views, maps, r))
    for axis in range(2):
        for m in (-0.1, 0.1):
            d = np.eye(3)[axis] * m
            moved = [dataclasses.replace(v, points=v.points - d) for v in views]
            assert np.array_equal(own_scores(batch, batch.shifted(d), maps),
                                  diagonal(moved, maps))


def test_rows_product_rounds_each_view_as_its_own_product() -> None:
    rng = np.random.default_rng(3)
    sizes = [1, 5, 1, 1, 40, 2, 1, 300]
    parts = [rng.normal(size=(s, 3)) * 30 for s in sizes]
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    R = rotvec_matrix(np.radians([2.0, -5.0, 1.0]))
    for M in (R, _K(91.3).T):
        got = rows_product(np.concatenate(parts), M, starts)
        assert np.array_equal(got, np.concatenate([p @ M for p in parts]))


def test_an_empty_batch_scores_nothing() -> None:
    batch = EdgeBatch.of([])
    assert batch.n == 0
    assert own_scores(batch, batch.points, np.zeros((*HW, 0, 2))).shape == (0,)


def _edges(rng: np.random.Generator, p: int) -> ScanEdges:
    pts = np.column_stack([rng.uniform(-8, 8, p), rng.uniform(-8, 8, p), rng.uniform(-2, 2, p)])
    acr = rng.normal(size=(p, 3))
    return ScanEdges(pts, rng.uniform(0.1, 1, p), acr / np.linalg.norm(acr, axis=1)[:, None])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10**6), n=st.integers(1, 10), same_k=st.booleans())
def test_camera_edges_many_equal_camera_edges_view_by_view(seed: int, n: int,
                                                            same_k: bool) -> None:
    rng = np.random.default_rng(seed)
    edges = [_edges(rng, int(rng.choice([0, 1, 2, int(rng.integers(3, 500))])))
             for _ in range(n)]
    T = []
    for _ in range(n):
        t = np.eye(4)
        t[:3, :3] = rotvec_matrix(rng.normal(0, 1.0, 3))
        t[:3, 3] = rng.normal(0, 1, 3)
        T.append(t)
    Ks = [_K(80.0) if same_k else _K(float(rng.uniform(60, 120))) for _ in range(n)]
    greys = [np.zeros(HW) for _ in range(n)]
    got = camera_edges_many(edges, T, Ks, greys)
    assert len(got) == n
    for g, e, t, k, grey in zip(got, edges, T, Ks, greys, strict=True):
        ref = camera_edges(e, t, k, grey)
        for a, b in zip((g.points, g.weights, g.normals, g.K, g.grey),
                        (ref.points, ref.weights, ref.normals, ref.K, ref.grey), strict=True):
            assert a.shape == b.shape and np.array_equal(a, b)
    assert camera_edges_many([], [], [], []) == []
