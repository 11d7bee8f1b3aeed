"""LiDAR reprojection of source latents into a target view (pure math, no I/O).

A target cell with LiDAR support (packet validity 1, mean depth d > 0 m) is lifted to the 3D
point X = T_world_tgt [d K_tgt^-1 (u, v, 1)] at its cell centre (u, v) (pixels), projected into
each source camera, and the source latent is read there (nearest cell or bilinear). Where
several sources see X, visibility decides by depth order: a source whose own packet depth at
the sampled cell lies in front of X (by more than `rel_tol` of X's depth) is occluded and
dropped; sources whose packet depth confirms X (within `rel_tol`) come before sources without
a usable depth there; among equals the source nearest to X (smallest depth) wins, ties to the
lowest source index.

Conventions follow `model.camera`: OpenCV pinhole cameras (K in pixels of an `image_hw`
image, x right, y down, z forward), `T_a_b` maps frame b into frame a (metres), pixel
centres at integer coordinates, cell (i, j) of an (H, W) grid centred at pixel
((j + 0.5) sx - 0.5, (i + 0.5) sy - 0.5) with sx = w / W, sy = h / H; a pixel is inside the
image when -0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5 (edges included, as
`packets.projection.in_image`), and its cell is floor((u + 0.5) / sx) clipped to the grid
(as `packets.support.cell_ids`). All geometry is float64.

`warp_latents` is the entry point: the reprojection baseline (`model.evaluate`) and the
reprojection-consistency check (`pipeline.analysis.reprojection`) call it, and a packet mode
that feeds reprojected latents to the network can call it per target view.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from packets.projection import in_image, pinhole
from packets.rigid import camera_from_world, lift_pixels
from schemas.channels import VALIDITY, channel_index

VALID_CHANNEL = channel_index(VALIDITY)
"""Index of the validity channel m in packet geometry g (`schemas.packed_cells.VALID_CHANNEL`)."""

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]
I64 = npt.NDArray[np.int64]

Sampling = Literal["nearest", "bilinear"]
MIN_DEPTH_M = 1e-3
"""Projected depth (m) at or below which a point counts as behind the camera."""
REL_TOL = 0.1
"""Relative depth tolerance of the visibility test (cell mean depths are coarse)."""


@dataclass(frozen=True)
class Reprojection:
    """Target cells projected into S sources.

    cell: (S, H, W, 2) continuous (row, col) source cell coordinates (cell centres integral);
    depth: (S, H, W) the point's depth in each source camera (m; NaN where unsupported);
    inside: (S, H, W) supported, in front of the source camera and inside its image;
    supported: (H, W) target cells with LiDAR support.
    """

    cell: F64
    depth: F64
    inside: B
    supported: B


@dataclass(frozen=True)
class Warp:
    """A reprojected latent grid: latent (C, H, W) float64, valid (H, W) cells some source
    filled, source (H, W) int64 the chosen source index (-1 where none)."""

    latent: F64
    valid: B
    source: I64


def cell_centres(grid_hw: tuple[int, int], image_hw: tuple[int, int]) -> F64:
    """Pixel coordinates (u, v) of the cell centres, (H, W, 2) float64."""
    (gh, gw), (h, w) = grid_hw, image_hw
    v = (np.arange(gh, dtype=np.float64) + 0.5) * (h / gh) - 0.5
    u = (np.arange(gw, dtype=np.float64) + 0.5) * (w / gw) - 0.5
    vv, uu = np.meshgrid(v, u, indexing="ij")
    return np.stack([uu, vv], axis=-1)


def subcell_pixels(grid_hw: tuple[int, int], image_hw: tuple[int, int],
                   per_side: int) -> F64:
    """Pixels (H, W, per_side^2, 2) (u, v) spread evenly over each cell of an (H, W) grid."""
    (gh, gw), (h, w) = grid_hw, image_hw
    offs = (np.arange(per_side) + 0.5) / per_side - 0.5  # fractions of a cell
    du, dv = np.meshgrid(offs * (w / gw), offs * (h / gh), indexing="xy")
    centres = cell_centres(grid_hw, image_hw)  # (H, W, 2)
    out: F64 = centres[:, :, None, :] + np.stack([du.ravel(), dv.ravel()], -1)[None, None]
    return out


def lift(depth: F64, K: F64, T_world_cam: F64, image_hw: tuple[int, int]) -> F64:
    """World points (H, W, 3) m of the cell centres of an (H, W) depth grid (z-depth, m)."""
    return lift_pixels(cell_centres(depth.shape[:2], image_hw), depth, K, T_world_cam)


def project(points: F64, K: F64, T_world_cam: F64) -> tuple[F64, F64]:
    """Pixels (..., 2) and z-depths (..., ) m of world points (..., 3) in one camera.

    Points at z <= 0 get NaN pixels (never inside an image)."""
    return pinhole(camera_from_world(points, T_world_cam), K)


def pixel_to_cell(uv: F64, grid_hw: tuple[int, int], image_hw: tuple[int, int]) -> F64:
    """Continuous (row, col) cell coordinates (..., 2) of pixels (..., 2) (u, v)."""
    (gh, gw), (h, w) = grid_hw, image_hw
    col = (uv[..., 0] + 0.5) * (gw / w) - 0.5
    row = (uv[..., 1] + 0.5) * (gh / h) - 0.5
    return np.stack([row, col], axis=-1)


def nearest_cell(cell: F64, grid_hw: tuple[int, int]) -> tuple[I64, I64]:
    """Integer (row, col) (...,) of continuous cell coordinates: floor(c + 0.5) clipped."""
    gh, gw = grid_hw
    c = np.nan_to_num(cell, nan=0.0)
    row = np.clip(np.floor(c[..., 0] + 0.5), 0, gh - 1).astype(np.int64)
    col = np.clip(np.floor(c[..., 1] + 0.5), 0, gw - 1).astype(np.int64)
    return row, col


def reproject(depth: F64, K_tgt: F64, T_tgt: F64, K_src: F64, T_src: F64,
              image_hw: tuple[int, int], min_depth_m: float = MIN_DEPTH_M) -> Reprojection:
    """Project the supported cells of a target depth grid into S source cameras.

    depth: (H, W) target z-depth per cell (m); cells with 0, a negative or a non-finite
    depth are unsupported. K_tgt (3, 3), T_tgt (4, 4) T_world_cam of the target; K_src
    (S, 3, 3), T_src (S, 4, 4) of the sources; image_hw the image size all K refer to.
    """
    d = np.asarray(depth, np.float64)
    supported = np.isfinite(d) & (d > 0)
    X = lift(np.where(supported, d, np.nan), K_tgt, T_tgt, image_hw)  # (H, W, 3)
    cells, depths, inside = [], [], []
    for K, T in zip(np.asarray(K_src), np.asarray(T_src), strict=True):
        uv, z = project(X, K, T)
        ok = supported & np.isfinite(z) & (z > min_depth_m)
        cells.append(pixel_to_cell(uv, d.shape, image_hw))
        depths.append(np.where(supported, z, np.nan))
        inside.append(ok & in_image(uv, image_hw))
    return Reprojection(np.stack(cells), np.stack(depths), np.stack(inside), supported)


def choose_sources(rep: Reprojection, src_depth: F64, rel_tol: float = REL_TOL) -> I64:
    """Per target cell the source to read (H, W) int64, -1 where no source sees the point.

    src_depth: (S, H, W) each source's own packet depth per cell (m; 0 or NaN: no support).
    Ranking (module docstring): occluded sources dropped; confirmed before unknown; then
    smallest depth; then lowest index.
    """
    S = rep.depth.shape[0]
    row, col = nearest_cell(rep.cell, rep.supported.shape)  # (S, H, W)
    own = np.asarray(src_depth, np.float64)[np.arange(S)[:, None, None], row, col]
    known = np.isfinite(own) & (own > 0)
    z = np.nan_to_num(rep.depth, nan=np.inf)
    occluded = known & (own < z * (1.0 - rel_tol))
    confirmed = known & (np.abs(own - z) <= rel_tol * z)
    usable = rep.inside & ~occluded
    # lexicographic key: (unconfirmed, depth, index); unusable sources rank last
    key_rank = np.where(usable, np.where(confirmed, 0.0, 1.0), 2.0)
    order = np.lexsort((np.broadcast_to(np.arange(S)[:, None, None], z.shape), z, key_rank),
                       axis=0)
    best = order[0]  # (H, W)
    any_usable = usable.any(axis=0)
    out: I64 = np.where(any_usable, best, -1).astype(np.int64)
    return out


def sample(latents: F64, cell: F64, mode: Sampling = "nearest") -> F64:
    """Latents (C, H', W') read at continuous cells (..., 2) -> (C, ...) float64.

    nearest: the cell floor(c + 0.5) (clipped); bilinear: the four neighbours weighted,
    coordinates clamped to the grid (edge cells repeat outward)."""
    lat = np.asarray(latents, np.float64)
    grid = lat.shape[1:]
    if mode == "nearest":
        r, c = nearest_cell(cell, (grid[0], grid[1]))
        out: F64 = lat[:, r, c]
        return out
    if mode != "bilinear":
        raise ValueError(f"sampling {mode!r}: one of nearest, bilinear")
    cc = np.nan_to_num(cell, nan=0.0)
    r = np.clip(cc[..., 0], 0, grid[0] - 1)
    c = np.clip(cc[..., 1], 0, grid[1] - 1)
    r0 = np.minimum(np.floor(r).astype(np.int64), grid[0] - 1)
    c0 = np.minimum(np.floor(c).astype(np.int64), grid[1] - 1)
    r1, c1 = np.minimum(r0 + 1, grid[0] - 1), np.minimum(c0 + 1, grid[1] - 1)
    fr, fc = r - r0, c - c0
    out = (lat[:, r0, c0] * (1 - fr) * (1 - fc) + lat[:, r0, c1] * (1 - fr) * fc
           + lat[:, r1, c0] * fr * (1 - fc) + lat[:, r1, c1] * fr * fc)
    return out


def warp_latents(src_latents: F64, depth: F64, K_tgt: F64, T_tgt: F64, K_src: F64,
                 T_src: F64, src_depth: F64, image_hw: tuple[int, int],
                 mode: Sampling = "nearest", rel_tol: float = REL_TOL) -> Warp:
    """The target's latent grid reprojected from S sources.

    src_latents: (S, C, H, W); depth: (H, W) target packet depth (m, 0 = no support);
    src_depth: (S, H, W) the sources' packet depths (m, 0 = no support); cameras as
    `reproject`. Cells no source fills are zero in `latent` and False in `valid`.
    """
    lat = np.asarray(src_latents, np.float64)
    rep = reproject(depth, K_tgt, T_tgt, K_src, T_src, image_hw)
    chosen = choose_sources(rep, src_depth, rel_tol)
    valid = chosen >= 0
    out = np.zeros((lat.shape[1], *valid.shape))
    for s in np.unique(chosen[valid]):
        m = chosen == s
        out[:, m] = sample(lat[s], rep.cell[s][m], mode)
    return Warp(out, valid, chosen)


def cells_to_pixels(mask: B, image_hw: tuple[int, int]) -> B:
    """A per-cell mask (H, W) as a per-pixel mask (h, w): each pixel takes its cell's value."""
    (gh, gw), (h, w) = mask.shape, image_hw
    rows = np.minimum((np.arange(h) * gh) // h, gh - 1)
    cols = np.minimum((np.arange(w) * gw) // w, gw - 1)
    out: B = np.asarray(mask, bool)[rows[:, None], cols[None, :]]
    return out


G_INV_DEPTH = 2
"""Index of the inverse mean depth (1/m) in packet geometry g: `inv_mean_depth` of the
explicit channels (packets.statistics.CHANNELS, eq. 9); validity is
`VALID_CHANNEL`."""


def packet_depth(g: npt.ArrayLike) -> F64:
    """Per-cell mean depth (..., H, W) m of packet geometry g (..., 6, H, W); 0 on cells
    without support (validity <= 0.5 or a non-positive inverse depth)."""
    a = np.asarray(g, np.float64)
    inv = a[..., G_INV_DEPTH, :, :]
    ok = (a[..., VALID_CHANNEL, :, :] > 0.5) & np.isfinite(inv) & (inv > 0)
    with np.errstate(divide="ignore"):
        out: F64 = np.where(ok, 1.0 / np.where(ok, inv, 1.0), 0.0)
    return out
