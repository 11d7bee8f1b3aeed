"""Support sets (eq. 8): which in-frustum point falls in which latent cell.

The latent grid has one cell per `PATCH_PX` x `PATCH_PX` pixel patch (224x336 -> 16x24). Cells are
numbered row-major: cell id = row * W_grid + col. A point belongs to the pixel round(u), round(v)
(OpenCV pixel centres); points exactly on the right/bottom image edge (u = W - 0.5) fall in the
last pixel, hence the last cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.projection import Projection
from schemas.errors import DataError

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]

PATCH_PX: int = 14
"""Side of one latent cell in pixels (DA3 / ViT patch size)."""


def grid_shape(hw: tuple[int, int], patch: int = PATCH_PX) -> tuple[int, int]:
    """Latent grid (H, W) in cells for an image of hw pixels; sides must be multiples of patch."""
    h, w = hw
    if patch <= 0 or h <= 0 or w <= 0 or h % patch or w % patch:
        raise DataError(f"image size {hw} must be positive multiples of the {patch} px patch")
    return h // patch, w // patch


def cell_ids(uv: F64, hw: tuple[int, int], patch: int = PATCH_PX) -> I64:
    """Flat cell id (M,) int64 of (M, 2) in-image pixel coordinates."""
    gw = grid_shape(hw, patch)[1]
    col = np.clip(np.floor(uv[:, 0] + 0.5).astype(np.int64), 0, hw[1] - 1) // patch
    row = np.clip(np.floor(uv[:, 1] + 0.5).astype(np.int64), 0, hw[0] - 1) // patch
    return row * gw + col


@dataclass(frozen=True)
class SupportSets:
    """The in-frustum points of one sweep in one view and their cells.

    point_idx: (M,) int64 row of each in-frustum point in the sweep (and its feature array).
    cell: (M,) int64 flat cell id in [0, H*W).
    depth: (M,) float64 camera depth in metres (>= the minimum depth).
    grid_hw: latent grid (H, W).
    n_points / n_behind / n_too_near / n_outside: sweep size; points with z <= 0; points with
    0 < z < minimum depth (dropped and counted); points in front but outside the image.
    n_front_dropped: points removed by front-surface filtering (0 if not applied).
    """

    point_idx: I64
    cell: I64
    depth: F64
    grid_hw: tuple[int, int]
    n_points: int = 0
    n_behind: int = 0
    n_too_near: int = 0
    n_outside: int = 0
    n_front_dropped: int = 0

    @property
    def n_cells(self) -> int:
        """Number of latent cells H * W."""
        return self.grid_hw[0] * self.grid_hw[1]

    def counts(self) -> I64:
        """(n_cells,) int64 support size n_q per cell."""
        return np.bincount(self.cell, minlength=self.n_cells).astype(np.int64)


def support_sets(
    proj: Projection, hw: tuple[int, int], min_depth_m: float, patch: int = PATCH_PX
) -> SupportSets:
    """Build the support sets of one view from its projection (image size hw in pixels)."""
    grid = grid_shape(hw, patch)
    idx = np.flatnonzero(proj.valid).astype(np.int64)
    n_behind = int(np.count_nonzero(proj.depth <= 0))
    n_near = int(np.count_nonzero((proj.depth > 0) & (proj.depth < min_depth_m)))
    return SupportSets(
        point_idx=idx,
        cell=cell_ids(proj.uv[idx], hw, patch),
        depth=proj.depth[idx],
        grid_hw=grid,
        n_points=int(proj.depth.shape[0]),
        n_behind=n_behind,
        n_too_near=n_near,
        n_outside=int(proj.depth.shape[0]) - n_behind - n_near - int(idx.size),
    )


def front_margins(nearest: F64, margin_m: float, rel: float = 0.0) -> F64:
    """Per-cell front-surface margin (metres): `margin_m + rel * nearest` for nearest depths (n,).

    rel = 0 is the fixed margin; rel > 0 lets the margin follow the scene: a surface seen at a
    grazing angle spans a depth range across one cell that grows with its depth (about
    d^2 * patch / (f * height) for the ground), while an occluder's step stays a step.
    """
    for name, v in (("margin", margin_m), ("relative margin", rel)):
        if not v >= 0 or not np.isfinite(v):
            raise DataError(f"front-surface {name} must be finite and >= 0, got {v}")
    out: F64 = margin_m + rel * nearest
    return out


def front_surface(sup: SupportSets, margin_m: float, rel: float = 0.0) -> SupportSets:
    """Keep, per cell, only points within `front_margins` metres behind the cell's nearest point."""
    nearest = np.full(sup.n_cells, np.inf)
    np.minimum.at(nearest, sup.cell, sup.depth)
    margin = front_margins(nearest[sup.cell], margin_m, rel)
    keep = sup.depth <= nearest[sup.cell] + margin
    return SupportSets(
        point_idx=sup.point_idx[keep],
        cell=sup.cell[keep],
        depth=sup.depth[keep],
        grid_hw=sup.grid_hw,
        n_points=sup.n_points,
        n_behind=sup.n_behind,
        n_too_near=sup.n_too_near,
        n_outside=sup.n_outside,
        n_front_dropped=sup.n_front_dropped + int(keep.size - np.count_nonzero(keep)),
    )
