"""Packet assembly: agreement with the reference pipeline, modes, NaN/Inf rejection, edge sweeps."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

import packets.assemble as assemble
from packets.assemble import Packet, SweepFeatures, build_packet
from packets.reference import (
    reference_cell_stats,
    reference_explicit,
    reference_pool_mean,
    reference_project_point,
)
from tests.strategies import delta_tau_s, depths_m, non_finite

HW = (28, 42)
GRID = (2, 3)
K = np.array([[30.0, 0.0, 20.5], [0.0, 30.0, 13.5], [0.0, 0.0, 1.0]])
T = np.array([[0.0, -1.0, 0.0, 0.1], [0.0, 0.0, -1.0, 0.2], [1.0, 0.0, 0.0, -0.3], [0, 0, 0, 1]])


def _sweep(seed: int, n: int = 400, c: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform([-5.0, -20.0, -10.0], [40.0, 20.0, 10.0], (n, 3))  # lidar: x forward
    return xyz, rng.standard_normal((n, c)).astype(np.float32)


def _reference_packet(
    xyz: np.ndarray, feat: np.ndarray, dt: float, min_depth: float = 0.1
) -> tuple[np.ndarray, np.ndarray]:
    """g (6, H, W), h (C, H, W) float64 with per-point and per-cell loops."""
    idx, cells, depths = [], [], []
    for k, p in enumerate(xyz):
        c = T[:3, :3] @ p + T[:3, 3]
        if c[2] < min_depth:
            continue
        u, v = reference_project_point(tuple(c), K, "pinhole", np.zeros(5))
        if -0.5 <= u <= HW[1] - 0.5 and -0.5 <= v <= HW[0] - 0.5:
            col = min(math.floor(u + 0.5), HW[1] - 1) // 14
            row = min(math.floor(v + 0.5), HW[0] - 1) // 14
            idx.append(k)
            cells.append(row * GRID[1] + col)
            depths.append(c[2])
    i, q, d = np.array(idx, np.int64), np.array(cells, np.int64), np.array(depths)
    g = reference_explicit(*reference_cell_stats(q, d, 6), dt, GRID)
    h = reference_pool_mean(feat, i, q, 6).T.reshape(-1, *GRID)
    return g, h


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dt=delta_tau_s)
def test_full_packet_matches_reference(seed: int, dt: float) -> None:
    xyz, feat = _sweep(seed)
    p = build_packet(xyz, K, T, HW, dt, feat)
    g_ref, h_ref = _reference_packet(xyz, feat, dt)
    assert p.g is not None and p.h is not None
    np.testing.assert_allclose(p.g, g_ref.astype(np.float32), rtol=2e-6)
    np.testing.assert_allclose(p.h, h_ref, rtol=1e-5, atol=1e-6)
    assert p.counts.sum() == p.stats.n_in_frustum
    assert np.isfinite(p.g).all() and np.isfinite(p.h).all()


def test_torch_features_and_shared_sweep_features() -> None:
    xyz, feat = _sweep(1)
    shared = SweepFeatures.from_array(torch.from_numpy(feat))
    T2 = T.copy()
    T2[:3, 3] += [0.5, 0.0, 0.0]
    for T_view in (T, T2):  # two views of one sweep, one validated feature array
        a = build_packet(xyz, K, T_view, HW, 0.01, shared)
        b = build_packet(xyz, K, T_view, HW, 0.01, feat)
        assert a.h is not None and b.h is not None
        np.testing.assert_array_equal(a.h, b.h)


def test_modes() -> None:
    xyz, feat = _sweep(2)
    full = build_packet(xyz, K, T, HW, 0.02, feat)
    nan_feat = np.full_like(feat, np.nan)  # never read outside 'full'
    geom = build_packet(xyz, K, T, HW, 0.02, nan_feat, mode="geom_only")
    zero = build_packet(xyz, K, T, HW, 0.02, nan_feat, mode="zero")
    none = build_packet(xyz, K, T, HW, 0.02, None, mode="no_lidar")
    assert geom.h is None and geom.g is not None and full.g is not None
    np.testing.assert_array_equal(geom.g, full.g)
    assert zero.g is not None and zero.h is not None
    assert zero.h.shape == (5, *GRID) and not zero.g.any() and not zero.h.any()
    assert none.g is None and none.h is None
    for p in (geom, zero, none):
        np.testing.assert_array_equal(p.counts, full.counts)
    t = geom.tensor(5)
    assert t.shape == (11, *GRID) and not t[6:].any()
    np.testing.assert_array_equal(full.tensor(5)[6:], full.h)
    with pytest.raises(ValueError, match="no_lidar"):
        none.tensor(5)
    with pytest.raises(ValueError, match="c_u"):
        build_packet(xyz, K, T, HW, 0.0, None, mode="zero")
    with pytest.raises(ValueError, match="mode"):
        build_packet(xyz, K, T, HW, 0.0, feat, mode="half")  # type: ignore[arg-type]


@pytest.mark.parametrize("target", ["xyz", "K", "T_cam_lidar", "point features", "delta_tau_s"])
@given(bad=non_finite)
def test_non_finite_rejected_before_pooling(target: str, bad: float) -> None:
    xyz, feat = _sweep(3, n=50)
    args: dict[str, np.ndarray] = {"xyz": xyz, "K": K.copy(), "T_cam_lidar": T.copy()}
    dt = 0.0
    if target == "point features":
        feat[7, 2] = bad
    elif target == "delta_tau_s":
        dt = bad
    else:
        args[target] = args[target].copy()
        args[target][1, 1] = bad

    def no_pooling(*_: object, **__: object) -> None:
        raise AssertionError("pooling reached with non-finite input")

    mp = pytest.MonkeyPatch()
    mp.setattr(assemble, "pool_support", no_pooling)
    try:
        with pytest.raises(ValueError, match=target):
            build_packet(args["xyz"], args["K"], args["T_cam_lidar"], HW, dt, feat)
    finally:
        mp.undo()


def test_empty_sweep_and_all_behind_give_zero_packets() -> None:
    empty = build_packet(np.zeros((0, 3)), K, T, HW, 0.0, np.zeros((0, 4), np.float32))
    behind = build_packet(np.full((9, 3), -2.0), K, T, HW, 0.0, np.ones((9, 4), np.float32))
    for p in (empty, behind):
        assert p.g is not None and p.h is not None
        assert p.g.shape == (6, *GRID) and p.h.shape == (4, *GRID)
        assert not p.g.any() and not p.h.any() and not p.counts.any()
    assert behind.stats.n_behind == 9


def test_front_surface_at_a_depth_discontinuity() -> None:
    # one cell seen through: a near layer at 5 m (feature +1) and a far layer at 20 m (feature -1)
    uv_cam = [(5.0, 0.0, 0.0), (5.0, 0.01, 0.0), (20.0, 0.0, 0.0), (20.0, 0.02, 0.01)]
    xyz = np.array(uv_cam)
    feat = np.array([[1.0], [1.0], [-1.0], [-1.0]], dtype=np.float32)
    plain = build_packet(xyz, K, T, HW, 0.0, feat)
    front = build_packet(xyz, K, T, HW, 0.0, feat, front_margin_m=0.5)
    assert plain.g is not None and front.g is not None and front.h is not None
    q = np.unravel_index(np.argmax(plain.counts), GRID)
    assert plain.counts[q] == 4 and front.counts[q] == 2
    # camera depth = lidar x - 0.3 m: front mean 4.7 m (not 12.2 m), variance 0 (not 56.25 m^2)
    assert front.g[2][q] == pytest.approx(1 / 4.7) and plain.g[2][q] == pytest.approx(1 / 12.2)
    assert front.g[4][q] == 0.0 and plain.g[4][q] == pytest.approx(56.25)
    assert front.h[0][q] == pytest.approx(1.0) and front.stats.n_front_dropped == 2


def test_packet_is_a_dataclass_with_numpy_outputs() -> None:
    xyz, feat = _sweep(4)
    p = build_packet(xyz, K, T, HW, 0.0, torch.from_numpy(feat))
    assert isinstance(p, Packet) and isinstance(p.h, np.ndarray) and p.counts.dtype == np.int64


def test_packets_import_nothing_from_pipeline_or_model() -> None:
    root = Path(assemble.__file__).parent
    for path in root.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names.append(node.module)
            assert not any(n.split(".")[0] in {"pipeline", "model", "dags"} for n in names), path


@settings(max_examples=30, deadline=None)
@given(
    depths=st.lists(st.sampled_from([1e-3, 0.37, 12.5, 1e4]) | depths_m, min_size=1, max_size=40),
    seed=st.integers(0, 2**32 - 1),
    dt=delta_tau_s,
)
@example(depths=[1e-3, 1e4, 1e-3, 9999.999999999998], seed=1, dt=0.0)  # found in CI
def test_extreme_depths_end_to_end(depths: list[float], seed: int, dt: float) -> None:
    """Points at 1 mm .. 10 km placed on known pixels: g equals the float64 reference."""
    rng = np.random.default_rng(seed)
    d = np.array(depths)
    px = rng.integers(0, [HW[1], HW[0]], (d.size, 2))  # integer pixels: no rounding ambiguity
    cam = np.column_stack(
        [(px[:, 0] - K[0, 2]) / K[0, 0] * d, (px[:, 1] - K[1, 2]) / K[1, 1] * d, d]
    )
    p = build_packet(cam, K, np.eye(4), HW, dt, None, mode="geom_only", min_depth_m=5e-4)
    cell = (px[:, 1] // 14) * GRID[1] + px[:, 0] // 14
    ref = reference_explicit(*reference_cell_stats(cell, d, 6), dt, GRID)
    assert p.g is not None and np.isfinite(p.g).all() and p.stats.n_in_frustum == d.size
    # Absolute floor: the depth variance of points a few float64 ulps apart is itself only
    # known to (ulp(depth))^2 (the reference's two-pass mean rounds to an endpoint, e.g. 1.65e-24
    # m^2 where the exact variance of (1e4, 1e4 - 1.8e-12) is 8.3e-25); at most 8e-23 m^2 here.
    floor = (4 * np.finfo(np.float64).eps * d.max()) ** 2
    np.testing.assert_allclose(p.g, ref.astype(np.float32), rtol=2e-6, atol=floor)
