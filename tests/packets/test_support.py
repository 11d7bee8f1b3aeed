"""Support sets: grid shape, cell ids at cell and image borders, accounting, front surface."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.projection import project_points
from packets.support import (
    PATCH_PX,
    SupportSets,
    cell_ids,
    front_margins,
    front_surface,
    grid_shape,
    support_sets,
)
from schemas.errors import DataError

HW = (28, 42)  # 2 x 3 cells


def test_grid_shape_paper_size() -> None:
    assert grid_shape((224, 336)) == (16, 24)
    with pytest.raises(ValueError, match="multiples"):
        grid_shape((225, 336))


@pytest.mark.parametrize(
    ("u", "v", "cell"),
    [
        (-0.5, -0.5, 0),  # top-left image corner
        (13.4999, 0.0, 0),  # last pixel of the first patch
        (13.5, 0.0, 1),  # pixel 14: first pixel of the second patch
        (41.5, 27.5, 5),  # bottom-right image corner (right/bottom border, inclusive)
        (41.0, 13.4999, 2),
        (41.0, 13.5, 5),
    ],
)
def test_cell_ids_at_borders(u: float, v: float, cell: int) -> None:
    assert cell_ids(np.array([[u, v]]), HW)[0] == cell


@settings(max_examples=100, deadline=None)
@given(u=st.floats(-0.5, 41.5), v=st.floats(-0.5, 27.5))
def test_cell_ids_match_pixel_rounding(u: float, v: float) -> None:
    px = min(math.floor(u + 0.5), HW[1] - 1)
    py = min(math.floor(v + 0.5), HW[0] - 1)
    expected = (py // PATCH_PX) * (HW[1] // PATCH_PX) + px // PATCH_PX
    assert cell_ids(np.array([[u, v]]), HW)[0] == expected


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300))
def test_every_point_accounted_for(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-20, 20, (n, 3))
    xyz[: n // 10, 2] = 0.0  # some exactly on the camera plane
    K = np.array([[30.0, 0, 20.5], [0, 30.0, 13.5], [0, 0, 1]])
    sup = support_sets(project_points(xyz, K, np.eye(4), HW), HW, 0.1)
    assert sup.n_behind + sup.n_too_near + sup.n_outside + sup.point_idx.size == n
    assert np.all(sup.depth >= 0.1)
    assert sup.counts().sum() == sup.point_idx.size
    assert sup.cell.size == 0 or (sup.cell.min() >= 0 and sup.cell.max() < 6)


def _sup(cell: list[int], depth: list[float]) -> SupportSets:
    return SupportSets(
        point_idx=np.arange(len(cell), dtype=np.int64),
        cell=np.array(cell, dtype=np.int64),
        depth=np.array(depth),
        grid_hw=(2, 3),
        n_points=len(cell),
    )


def test_front_surface_keeps_nearest_layer() -> None:
    sup = _sup([0, 0, 0, 0, 4, 4], [5.0, 5.3, 20.0, 21.0, 9.0, 9.5])
    out = front_surface(sup, 0.5)
    np.testing.assert_array_equal(out.point_idx, [0, 1, 4, 5])
    assert out.n_front_dropped == 2
    np.testing.assert_array_equal(front_surface(sup, 0.0).point_idx, [0, 4])
    np.testing.assert_array_equal(front_surface(sup, 1e9).point_idx, np.arange(6))


@pytest.mark.parametrize("margin", [-1.0, float("nan"), float("inf")])
def test_front_surface_bad_margin(margin: float) -> None:
    with pytest.raises(ValueError, match="margin"):
        front_surface(_sup([0], [1.0]), margin)


# --- boundaries the mutation run asked for ------------------------------------------------------


@pytest.mark.parametrize(("hw", "patch"), [((0, 14), 14), ((14, 0), 14), ((-14, 14), 14),
                                           ((14, -14), 14), ((14, 14), 0), ((14, 14), -7),
                                           ((15, 14), 14), ((14, 15), 14)])
def test_grid_shape_refuses_non_positive_or_non_multiple_sizes(hw: tuple[int, int],
                                                               patch: int) -> None:
    with pytest.raises(DataError, match=rf"^image size \({hw[0]}, {hw[1]}\) must be positive "
                                        rf"multiples of the {patch} px patch$"):
        grid_shape(hw, patch)


def test_one_pixel_patches_and_one_pixel_images() -> None:
    assert grid_shape((1, 1), 1) == (1, 1)
    assert grid_shape((2, 1), 1) == (2, 1)
    uv = np.array([[-0.5, -0.5], [0.0, 0.0], [2.5, 1.5], [2.0, 1.0], [1.49, 0.5]])
    np.testing.assert_array_equal(cell_ids(uv, (2, 3), 1), [0, 0, 5, 5, 4])


def test_cell_ids_use_the_given_patch() -> None:
    uv = np.array([[6.4, 0.0], [6.5, 0.0], [13.5, 13.5]])  # pixel 6, pixel 7, last pixel
    np.testing.assert_array_equal(cell_ids(uv, (14, 14), 7), [0, 1, 3])
    proj = project_points(np.array([[0.0, 0.0, 1.0], [0.3, 0.3, 1.0]]),
                          np.array([[20.0, 0.0, 3.0], [0.0, 20.0, 3.0], [0.0, 0.0, 1.0]]),
                          np.eye(4), (14, 14))
    sup = support_sets(proj, (14, 14), 0.1, patch=7)
    assert sup.grid_hw == (2, 2)
    np.testing.assert_array_equal(sup.cell, [0, 3])


def test_a_point_exactly_at_the_minimum_depth_is_supported() -> None:
    K = np.array([[10.0, 0.0, 6.5], [0.0, 10.0, 6.5], [0.0, 0.0, 1.0]])
    pts = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.4999], [0.0, 0.0, -1.0], [50.0, 0.0, 1.0]])
    sup = support_sets(project_points(pts, K, np.eye(4), (14, 14), min_depth_m=0.5), (14, 14),
                       0.5)
    assert sup.point_idx.tolist() == [0]
    assert (sup.n_points, sup.n_behind, sup.n_too_near, sup.n_outside) == (4, 1, 1, 1)
    assert sup.counts().dtype == np.int64 and sup.counts().tolist() == [1]


def test_front_margins_default_to_a_fixed_margin_and_name_the_bad_one() -> None:
    np.testing.assert_array_equal(front_margins(np.array([1.0, 40.0]), 0.5), [0.5, 0.5])
    np.testing.assert_array_equal(front_margins(np.array([1.0, 40.0]), 0.5, 0.1), [0.6, 4.5])
    with pytest.raises(DataError, match=r"^front-surface margin must be finite and >= 0, got "
                                        r"-1.0$"):
        front_margins(np.ones(2), -1.0)
    with pytest.raises(DataError, match=r"^front-surface relative margin must be finite and >= 0, "
                                        r"got inf$"):
        front_margins(np.ones(2), 0.5, float("inf"))


def test_front_surface_keeps_the_drop_counts_of_the_support() -> None:
    sup = SupportSets(point_idx=np.arange(3), cell=np.array([0, 0, 1]),
                      depth=np.array([1.0, 5.0, 2.0]), grid_hw=(1, 2), n_points=9, n_behind=2,
                      n_too_near=3, n_outside=1, n_front_dropped=0)
    cut = front_surface(front_surface(sup, 0.5), 0.5)
    assert (cut.n_points, cut.n_behind, cut.n_too_near, cut.n_outside, cut.n_front_dropped) == (
        9, 2, 3, 1, 1)
    assert cut.point_idx.tolist() == [0, 2]


def test_counts_cover_every_cell_including_empty_trailing_ones() -> None:
    sup = SupportSets(point_idx=np.arange(3), cell=np.array([0, 2, 2]),
                      depth=np.ones(3), grid_hw=(2, 3))
    assert sup.counts().tolist() == [1, 0, 2, 0, 0, 0]
