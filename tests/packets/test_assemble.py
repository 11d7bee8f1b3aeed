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
from bench.support.packet_reference import (
    reference_cell_stats,
    reference_explicit,
    reference_pool_mean,
    reference_project_point,
)
from packets.assemble import (
    Packet,
    SweepFeatures,
    build_packet,
    packet_from_support,
    view_support,
)
from packets.projection import project_points
from packets.support import front_surface, support_sets
from schemas.errors import DataError
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


# --- pass-through, modes and refusals the mutation run asked for -------------------------------

D_EQUI = np.array([0.3, -0.1, 0.05, -0.01])


def test_camera_model_distortion_patch_and_min_depth_reach_the_support() -> None:
    xyz, feat = _sweep(20)
    kw = {"model": "equidistant", "D": D_EQUI, "min_depth_m": 8.0, "patch": 7}
    sup = view_support(xyz, K, T, HW, **kw)  # type: ignore[arg-type]
    proj = project_points(xyz, K, T, HW, model="equidistant", D=D_EQUI, min_depth_m=8.0)
    want = support_sets(proj, HW, 8.0, 7)
    np.testing.assert_array_equal(sup.point_idx, want.point_idx)
    np.testing.assert_array_equal(sup.cell, want.cell)
    np.testing.assert_array_equal(sup.depth, want.depth)
    assert sup.grid_hw == (4, 6) and sup.n_too_near > 0
    plain = view_support(xyz, K, T, HW)
    assert not np.array_equal(plain.point_idx, sup.point_idx)
    got = build_packet(xyz, K, T, HW, 0.01, feat, **kw)  # type: ignore[arg-type]
    ref = packet_from_support(want, 0.01, feat)
    np.testing.assert_array_equal(got.g, ref.g)
    np.testing.assert_array_equal(got.h, ref.h)
    assert got.stats == ref.stats


def test_every_mode_keeps_its_name_counts_and_stats() -> None:
    xyz, feat = _sweep(21)
    sup = view_support(xyz, K, T, HW)
    full = packet_from_support(sup, 0.0, feat)  # the default mode is 'full'
    assert full.mode == "full" and full.h is not None and full.g is not None
    for mode in ("geom_only", "zero", "no_lidar", "learnable"):
        pk = packet_from_support(sup, 0.0, feat, mode=mode)  # type: ignore[arg-type]
        assert pk.mode == mode
        assert pk.stats == full.stats
        np.testing.assert_array_equal(pk.counts, full.counts)
    assert packet_from_support(sup, 0.0, feat, mode="learnable").g is None
    assert packet_from_support(sup, 0.0, feat, mode="learnable").h is None
    with pytest.raises(DataError, match="a 'learnable' packet has no tensor"):
        packet_from_support(sup, 0.0, feat, mode="learnable").tensor(5)


def test_packet_stats_account_for_every_point() -> None:
    xyz, feat = _sweep(22)
    sup = view_support(xyz, K, T, HW)
    pk = packet_from_support(sup, 0.0, feat, front_margin_m=0.5)
    cut = front_surface(sup, 0.5)
    s = pk.stats
    assert (s.n_points, s.n_behind, s.n_too_near, s.n_outside) == (
        400, sup.n_behind, sup.n_too_near, sup.n_outside)
    assert s.n_front_dropped == cut.n_front_dropped > 0
    assert s.n_in_frustum == sup.point_idx.size == cut.point_idx.size + cut.n_front_dropped
    assert s.n_occupied_cells == np.count_nonzero(pk.counts) == np.unique(cut.cell).size
    assert s.n_points == s.n_behind + s.n_too_near + s.n_outside + s.n_in_frustum


def test_front_margin_and_its_relative_part_are_both_applied() -> None:
    xyz, feat = _sweep(23)
    sup = view_support(xyz, K, T, HW)
    for rel in (0.0, 0.1):
        pk = packet_from_support(sup, 0.0, feat, front_margin_m=0.5, front_margin_rel=rel)
        np.testing.assert_array_equal(pk.counts.ravel(),
                                      np.bincount(front_surface(sup, 0.5, rel).cell, minlength=6))
    assert not np.array_equal(
        packet_from_support(sup, 0.0, feat, front_margin_m=0.5).counts,
        packet_from_support(sup, 0.0, feat, front_margin_m=0.5, front_margin_rel=0.1).counts)
    assert not np.array_equal(
        packet_from_support(sup, 0.0, feat, front_margin_m=0.5).counts,
        packet_from_support(sup, 0.0, feat, front_margin_m=0.0).counts)


def test_zero_mode_sizes_h_from_c_u_first_then_the_features() -> None:
    xyz, feat = _sweep(24, c=3)
    sup = view_support(xyz, K, T, HW)
    by_c_u = packet_from_support(sup, 0.0, feat, mode="zero", c_u=5)
    by_feat = packet_from_support(sup, 0.0, feat, mode="zero")
    assert by_c_u.h is not None and by_c_u.h.shape == (5, *GRID)
    assert by_feat.h is not None and by_feat.h.shape == (3, *GRID)
    assert by_c_u.g is not None and by_c_u.g.dtype == by_c_u.h.dtype == np.float32
    assert build_packet(xyz, K, T, HW, 0.0, None, mode="zero", c_u=4).h.shape == (4, *GRID)  # type: ignore[union-attr]
    with pytest.raises(DataError, match=r"^mode 'zero' needs c_u or the features to size h$"):
        packet_from_support(sup, 0.0, None, mode="zero")


def test_tensor_stacks_g_and_h_in_float32() -> None:
    xyz, feat = _sweep(25, c=4)
    pk = build_packet(xyz, K, T, HW, 0.02, feat)
    out = pk.tensor(4)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out[:6], pk.g)
    np.testing.assert_array_equal(out[6:], pk.h)
    with pytest.raises(DataError, match=r"^packet h has 4 channels, expected C_u=3$"):
        pk.tensor(3)


def test_pooling_method_is_passed_on() -> None:
    xyz, feat = _sweep(26)
    sup = view_support(xyz, K, T, HW)
    for values in (feat, torch.from_numpy(feat)):
        with pytest.raises(DataError, match="unknown pooling method"):
            packet_from_support(sup, 0.0, values, method="magic")  # type: ignore[arg-type]


@pytest.mark.parametrize(("feat", "message"), [
    (None, r"^mode 'full' needs the sweep's point features$"),
    (np.zeros((3, 2), np.float32), r"^point features have 3 rows for a sweep of 4 points$"),
    (np.zeros(4, np.float32), r"^point features must be \(N, C_u\), got shape \(4,\)$"),
    (np.zeros((4, 2), np.int32), r"^point features must be floating point, got int32$"),
    (np.array([[0.0, 1.0]] * 3 + [[np.nan, 0.0]]), r"^point features has 1 non-finite"),
])
def test_bad_features_are_refused_by_name(feat: np.ndarray | None, message: str) -> None:
    with pytest.raises(DataError, match=message):
        build_packet(np.ones((4, 3)), K, T, HW, 0.0, feat)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_delta_tau_is_refused_by_name(bad: float) -> None:
    xyz, feat = _sweep(27)
    with pytest.raises(DataError, match=r"^delta_tau_s must be finite"):
        build_packet(xyz, K, T, HW, bad, feat)
    with pytest.raises(DataError, match=r"^delta_tau_s must be finite"):
        packet_from_support(view_support(xyz, K, T, HW), bad, feat, mode="geom_only")
    with pytest.raises(DataError, match=r"^packet mode must be one of \(.*\), got 'magic'$"):
        packet_from_support(view_support(xyz, K, T, HW), 0.0, feat, mode="magic")  # type: ignore[arg-type]
