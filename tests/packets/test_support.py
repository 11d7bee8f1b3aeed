"""Support sets: grid shape, cell ids at cell and image borders, accounting, front surface."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.projection import project_points
from packets.support import PATCH_PX, SupportSets, cell_ids, front_surface, grid_shape, support_sets

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
