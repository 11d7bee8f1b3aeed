"""Projection: OpenCV agreement, float64 round trip, cheirality, borders, NaN/Inf rejection."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.support.packet_reference import reference_project_point
from packets.projection import (
    MIN_DEPTH_M,
    backproject,
    bilinear,
    distort,
    in_image,
    pinhole,
    project_points,
    transform_points,
    undistort,
)
from packets.support import support_sets
from schemas.errors import DataError
from tests.strategies import depths_m, non_finite, pinhole_K, rigid_transforms

HW = (28, 42)
K0 = np.array([[30.0, 0.0, 20.5], [0.0, 30.0, 13.5], [0.0, 0.0, 1.0]])
D_RADTAN = np.array([-0.05, 0.01, 0.001, -0.002, 0.002])
D_EQUI = np.array([0.02, -0.01, 0.004, -0.001])


def _points_in_front(rng: np.random.Generator, n: int) -> np.ndarray:
    z = rng.uniform(0.5, 50.0, n)
    xy = rng.uniform(-0.8, 0.8, (n, 2)) * z[:, None]
    return np.column_stack([xy, z])


def test_pinhole_matches_opencv() -> None:
    pts = _points_in_front(np.random.default_rng(0), 200)
    uv, depth, _ = project_points(pts, K0, np.eye(4), HW, D=D_RADTAN)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K0, D_RADTAN)
    np.testing.assert_allclose(uv, ref[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(depth, pts[:, 2])


def test_equidistant_matches_opencv_fisheye() -> None:
    pts = _points_in_front(np.random.default_rng(1), 200)
    uv, _, _ = project_points(pts, K0, np.eye(4), HW, model="equidistant", D=D_EQUI)
    ref, _ = cv2.fisheye.projectPoints(pts[:, None], np.zeros(3), np.zeros(3), K0, D_EQUI)
    np.testing.assert_allclose(uv, ref[:, 0], rtol=0, atol=1e-9)


@pytest.mark.parametrize(("model", "D"), [("pinhole", None), ("equidistant", D_EQUI)])
def test_matches_reference_loop(model: str, D: np.ndarray | None) -> None:
    pts = _points_in_front(np.random.default_rng(2), 50)
    uv, _, _ = project_points(pts, K0, np.eye(4), HW, model=model, D=D)  # type: ignore[arg-type]
    dist = np.zeros(5) if D is None else D
    for k, p in enumerate(pts):
        np.testing.assert_allclose(uv[k], reference_project_point(tuple(p), K0, model, dist))


@settings(max_examples=60, deadline=None)
@given(
    K=pinhole_K(),
    T=rigid_transforms(),
    depth=depths_m,
    ndc=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)),
    model=st.sampled_from(["pinhole", "pinhole_radtan", "equidistant"]),
)
def test_project_backproject_round_trip(
    K: np.ndarray, T: np.ndarray, depth: float, ndc: tuple[float, float], model: str
) -> None:
    D = {"pinhole": None, "pinhole_radtan": D_RADTAN, "equidistant": D_EQUI}[model]
    cam_model = "equidistant" if model == "equidistant" else "pinhole"
    uv0 = np.array([[(ndc[0] + 1) / 2 * (HW[1] - 1), (ndc[1] + 1) / 2 * (HW[0] - 1)]])
    p_cam = backproject(uv0, np.array([depth]), K, cam_model, D)  # type: ignore[arg-type]
    p_lidar = transform_points(p_cam, np.linalg.inv(T))
    uv, d, valid = project_points(p_lidar, K, T, HW, cam_model, D, min_depth_m=5e-4)  # type: ignore[arg-type]
    assert valid[0]
    # float64 round trip through a metre-scale rigid transform: absolute error ~eps * |t|
    np.testing.assert_allclose(d, [depth], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(uv, uv0, rtol=0, atol=1e-8)
    back = transform_points(backproject(uv, d, K, cam_model, D), np.linalg.inv(T))  # type: ignore[arg-type]
    np.testing.assert_allclose(back, p_lidar, rtol=1e-9, atol=1e-9 * depth)


@settings(max_examples=40, deadline=None)
@given(z=st.one_of(st.just(0.0), st.just(-0.0), st.floats(-1e4, 0.0), st.floats(1e-12, 0.0999)))
def test_behind_camera_and_too_near_are_dropped_and_counted(z: float) -> None:
    pts = np.array([[0.0, 0.0, z], [0.1, -0.1, 2.0]])
    proj = project_points(pts, K0, np.eye(4), HW)
    assert not proj.valid[0] and proj.valid[1]
    np.testing.assert_array_equal(proj.uv[0], [-1.0, -1.0])
    assert np.isfinite(proj.uv).all()
    sup = support_sets(proj, HW, MIN_DEPTH_M)
    assert (sup.n_behind, sup.n_too_near) == ((1, 0) if z <= 0 else (0, 1))
    assert sup.n_behind + sup.n_too_near + sup.n_outside + sup.point_idx.size == 2


def test_image_borders_inclusive() -> None:
    h, w = HW
    uv = np.array([[-0.5, -0.5], [w - 0.5, h - 0.5], [-0.5000001, 3.0], [3.0, h - 0.4999999]])
    np.testing.assert_array_equal(in_image(uv, HW), [True, True, False, False])


def test_points_outside_image_invalid() -> None:
    pts = np.array([[100.0, 0.0, 1.0], [0.0, -100.0, 1.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(project_points(pts, K0, np.eye(4), HW).valid, [0, 0, 1])


@pytest.mark.parametrize("target", ["xyz", "K", "T_cam_lidar"])
@given(bad=non_finite)
def test_non_finite_inputs_rejected(target: str, bad: float) -> None:
    args = {"xyz": np.ones((4, 3)), "K": K0.copy(), "T_cam_lidar": np.eye(4)}
    args[target][1, 1] = bad
    with pytest.raises(ValueError, match=target):
        project_points(args["xyz"], args["K"], args["T_cam_lidar"], HW)


def test_overflowing_transform_rejected() -> None:
    T = np.eye(4)
    T[0, 3] = 1e308
    with pytest.raises(ValueError, match="camera-frame points"):
        project_points(np.array([[1.5e308, 0.0, 1.0]]), K0, T, HW)


def test_bad_camera_rejected() -> None:
    with pytest.raises(ValueError, match="focal"):
        project_points(np.ones((1, 3)), np.diag([0.0, 1.0, 1.0]), np.eye(4), HW)
    with pytest.raises(ValueError, match="coefficients"):
        project_points(np.ones((1, 3)), K0, np.eye(4), HW, model="equidistant", D=np.zeros(5))
    with pytest.raises(ValueError, match="model"):
        project_points(np.ones((1, 3)), K0, np.eye(4), HW, model="orthographic")  # type: ignore[arg-type]


def test_empty_sweep() -> None:
    proj = project_points(np.zeros((0, 3)), K0, np.eye(4), HW)
    assert proj.uv.shape == (0, 2) and proj.depth.shape == (0,) and proj.valid.shape == (0,)


# --- boundaries and refusals the mutation run asked for ----------------------------------------

K_SKEW = np.array([[30.0, 2.5, 20.5], [0.0, 28.0, 13.5], [0.0, 0.0, 1.0]])


def test_min_depth_is_inclusive_and_must_be_positive() -> None:
    pts = np.array([[0.0, 0.0, MIN_DEPTH_M], [0.0, 0.0, np.nextafter(MIN_DEPTH_M, 0.0)]])
    np.testing.assert_array_equal(project_points(pts, K0, np.eye(4), HW).valid, [True, False])
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(DataError, match=f"^min_depth_m must be > 0, got {bad}$"):
            project_points(pts, K0, np.eye(4), HW, min_depth_m=bad)


def test_skewed_intrinsics_match_the_reference_and_round_trip() -> None:
    """K[0, 1] (skew) enters u as in OpenCV's camera matrix (cv2.projectPoints itself ignores
    it, so the reference loop is the oracle here)."""
    pts = _points_in_front(np.random.default_rng(3), 50)
    uv, _, _ = project_points(pts, K_SKEW, np.eye(4), HW, D=D_RADTAN)
    for k, p in enumerate(pts):
        np.testing.assert_allclose(uv[k], reference_project_point(tuple(p), K_SKEW, "pinhole",
                                                                  D_RADTAN), rtol=1e-12)
    back = backproject(uv, pts[:, 2], K_SKEW, "pinhole", D_RADTAN)
    np.testing.assert_allclose(back, pts, rtol=1e-9, atol=1e-9)


def test_backproject_default_model_is_pinhole() -> None:
    uv = np.array([[3.0, 4.0], [20.5, 13.5]])
    np.testing.assert_array_equal(backproject(uv, [2.0, 5.0], K0),
                                  backproject(uv, [2.0, 5.0], K0, "pinhole", np.zeros(5)))


def test_principal_point_and_optical_axis_in_the_equidistant_model() -> None:
    """r = 0 (optical axis) and theta_d = 0 (principal point): the scale is 1, not 0/0."""
    proj = project_points(np.array([[0.0, 0.0, 4.0]]), K0, np.eye(4), HW, "equidistant", D_EQUI)
    np.testing.assert_array_equal(proj.uv, [[20.5, 13.5]])
    assert proj.valid.tolist() == [True]
    np.testing.assert_array_equal(distort(np.zeros((1, 2)), "equidistant", D_EQUI), [[0.0, 0.0]])
    back = backproject(np.array([[20.5, 13.5]]), [4.0], K0, "equidistant", D_EQUI)
    np.testing.assert_array_equal(back, [[0.0, 0.0, 4.0]])


def test_equidistant_undistort_converges_like_newton() -> None:
    """Strong fisheye coefficients up to 1.1 rad off axis: 5 Newton steps reach rounding."""
    D = np.array([0.3, -0.1, 0.05, -0.01])
    theta = np.linspace(0.05, 1.1, 8)
    xn = np.stack([np.tan(theta) * 0.6, np.tan(theta) * 0.8], axis=1)
    got = undistort(distort(xn, "equidistant", D), "equidistant", D, iterations=5)
    np.testing.assert_allclose(got, xn, rtol=0, atol=1e-13)


def test_non_finite_pixels_are_invalid_without_warnings() -> None:
    """A point far off axis just in front of the camera overflows the distortion polynomial:
    that point gets uv = -1 and is invalid, the others are unaffected, and no floating-point
    warning escapes (the suite turns warnings into errors)."""
    pts = np.array([[1e300, 0.0, 0.2], [0.1, -0.1, 2.0], [0.0, 1e300, 0.2]])
    proj = project_points(pts, K0, np.eye(4), HW, D=D_RADTAN)
    assert proj.valid.tolist() == [False, True, False]
    np.testing.assert_array_equal(proj.uv[[0, 2]], -1.0)
    np.testing.assert_allclose(proj.uv[1], [20.5 + 30 * 0.05, 13.5 - 30 * 0.05], atol=0.1)
    np.testing.assert_array_equal(proj.depth, [0.2, 2.0, 0.2])


def test_transform_points_computes_in_float64() -> None:
    T = np.eye(4, dtype=np.int64)
    T[0, 3] = 3
    out = transform_points(np.array([[1, 2, 3]]), T)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, [[4.0, 2.0, 3.0]])
    pts32 = np.array([[0.1, 0.2, 0.3]], dtype=np.float32)
    T32 = np.array([[0.6, -0.8, 0, 0.7], [0.8, 0.6, 0, 0.1], [0, 0, 1, 0.3], [0, 0, 0, 1]],
                   dtype=np.float32)
    want = pts32.astype(np.float64) @ T32[:3, :3].astype(np.float64).T + T32[:3, 3]
    np.testing.assert_array_equal(transform_points(pts32, T32), want)


@pytest.mark.parametrize(("fx", "fy"), [(0.0, 30.0), (30.0, 0.0), (30.0, -2.0), (-1.0, 30.0)])
def test_non_positive_focal_lengths_are_refused_with_both_values(fx: float, fy: float) -> None:
    K = np.array([[fx, 0.0, 20.5], [0.0, fy, 13.5], [0.0, 0.0, 1.0]])
    with pytest.raises(DataError, match=f"^K focal lengths must be positive, got fx={fx}, "
                                        f"fy={fy}$"):
        project_points(np.ones((1, 3)), K, np.eye(4), HW)


def test_small_positive_focal_lengths_are_accepted() -> None:
    K = np.array([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 1.0]])
    proj = project_points(np.array([[1.0, 2.0, 4.0]]), K, np.eye(4), (3, 3))
    np.testing.assert_array_equal(proj.uv, [[0.125, 0.25]])


def test_pinhole_takes_four_or_five_coefficients() -> None:
    pts = _points_in_front(np.random.default_rng(4), 20)
    four = project_points(pts, K0, np.eye(4), HW, D=D_RADTAN[:4])
    five = project_points(pts, K0, np.eye(4), HW, D=np.r_[D_RADTAN[:4], 0.0])
    np.testing.assert_array_equal(four.uv, five.uv)
    np.testing.assert_array_equal(backproject(four.uv, pts[:, 2], K0, "pinhole", D_RADTAN[:4]),
                                  backproject(five.uv, pts[:, 2], K0, "pinhole", five_d := np.r_[
                                      D_RADTAN[:4], 0.0]))
    assert five_d.size == 5
    with pytest.raises(DataError, match=r"^pinhole distortion D needs \(4, 5\) coefficients, "
                                        r"got 3$"):
        project_points(pts, K0, np.eye(4), HW, D=np.zeros(3))


@pytest.mark.parametrize(("args", "message"), [
    ({"xyz": np.ones((2, 2))}, r"^xyz must have shape \('\*', 3\), got \(2, 2\)$"),
    ({"xyz": np.array([[0.0, np.nan, 1.0]])}, r"^xyz has 1 non-finite value"),
    ({"T": np.eye(3)}, r"^T_cam_lidar must have shape \(4, 4\), got \(3, 3\)$"),
    ({"T": np.diag([1.0, np.inf, 1.0, 1.0])}, r"^T_cam_lidar has 1 non-finite value"),
    ({"K": np.eye(4)}, r"^K must have shape \(3, 3\), got \(4, 4\)$"),
    ({"K": np.diag([np.nan, 1.0, 1.0])}, r"^K has 1 non-finite value"),
    ({"D": [0.1, np.nan, 0.0, 0.0]}, r"^D has 1 non-finite value\(s\); first at index \(1,\)"),
])
def test_bad_inputs_are_refused_by_name(args: dict, message: str) -> None:
    call = {"xyz": np.ones((2, 3)), "K": K0, "T": np.eye(4), "D": None} | args
    with pytest.raises(DataError, match=message):
        project_points(call["xyz"], call["K"], call["T"], HW, D=call["D"])


def test_overflow_into_the_camera_frame_is_refused_by_name() -> None:
    T = np.eye(4)
    T[0, 3] = 1e308
    with pytest.raises(DataError, match=r"^camera-frame points \(T_cam_lidar applied to xyz\) "
                                        r"has 1 non-finite"):
        project_points(np.array([[1.5e308, 0.0, 1.0]]), K0, T, HW)


def test_a_margin_shrinks_the_image_and_nan_is_outside() -> None:
    h, w = HW
    uv = np.array([[0.0, 0.0], [w - 1.0, h - 1.0], [-1e-9, 3.0], [3.0, h - 1.0 + 1e-9],
                   [np.nan, 3.0]])
    np.testing.assert_array_equal(in_image(uv, HW, 0.5), [True, True, False, False, False])
    grid = np.stack(np.meshgrid([-0.5, 2.0], [1.0, h - 0.5], indexing="ij"), -1)  # (2, 2, 2)
    assert in_image(grid, HW).shape == (2, 2) and in_image(grid, HW).all()


def test_pinhole_matches_project_points_and_is_nan_behind() -> None:
    pts = np.array([[0.3, -0.2, 2.0], [1.0, 1.0, -1.0], [0.0, 0.0, 0.0]])
    uv, z = pinhole(pts, K0)
    ref = project_points(pts[:1], K0, np.eye(4), HW)
    np.testing.assert_allclose(uv[0], ref.uv[0], rtol=1e-12)
    np.testing.assert_array_equal(z, pts[:, 2])
    assert np.isnan(uv[1:]).all()


BH, BW = 28, 84  # the image the bilinear read is tested on


@settings(max_examples=50, deadline=None)
@given(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(0.0, 83.0), st.floats(0.0, 27.0))
def test_bilinear_is_exact_on_planes(a: float, b: float, u: float, v: float) -> None:
    vv, uu = np.meshgrid(np.arange(BH, dtype=float), np.arange(BW, dtype=float),
                         indexing="ij")
    img = (a * uu + b * vv)[..., None]
    got = bilinear(img, np.array([[u, v]]))[0, 0]
    assert got == pytest.approx(a * u + b * v, abs=1e-9 * (1 + abs(a) + abs(b)) * 100)



def test_bilinear_is_exact_on_a_linear_image_and_clamps_at_edges() -> None:
    v, u = np.mgrid[0:4, 0:5].astype(np.float64)
    img = (3 * u + 2 * v)[..., None]
    uv = np.array([[1.25, 2.5], [-3.0, 0.0], [4.0, 3.0], [3.999, 2.0]])
    np.testing.assert_allclose(bilinear(img, uv)[:, 0], [8.75, 0.0, 18.0, 15.997])
