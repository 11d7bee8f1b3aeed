"""Reprojection consistency of a synthesized target view (pure math, no I/O).

The paper scores a synthesized view's geometry by its "3D reprojection error". With the
embedded encoders there is no depth readout of a synthesized latent (docs/benchmarks_model.md,
"Reprojection consistency of synthesized views"), so the geometry is scored through the LiDAR
points the target was conditioned on, photometrically:

- every target cell with LiDAR support (packet depth d > 0 m) gives `per_side`^2 points spread
  over the cell, each lifted at the cell's depth with the target camera (a fronto-parallel
  facet per cell, as `packets.reprojection_consistency.lift_cells`);
- each point is projected into the source the reprojection chose for its cell
  (`packets.reprojection.choose_sources`: visibility by depth order; cells no source sees are
  left out) and the source image read there (bilinear); points that leave the source image's
  interior [0, w - 1] x [0, h - 1] are left out;
- a candidate target image is read at the point's own target pixel (bilinear), and

    err = sqrt( mean over points p and channels c of (I_cand[c](p) - I_src[c](p'))^2 )

  on intensities scaled to [0, 1] (uint8 / 255).

A candidate equal to the reprojected sources scores 0. The ground-truth target does not:
occlusions and depth edges inside a cell, view-dependent appearance and exposure leave a floor;
a model consistent with the LiDAR geometry scores near it, one that ignores the geometry scores
like a baseline that ignores it. Conventions (pixels, cells, poses) are `packets.reprojection`'s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.reprojection import cell_centres, project

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

PER_SIDE = 4
"""Points per cell side: 16 points per supported cell."""


@dataclass(frozen=True)
class Reads:
    """Where every scored point is read: its target pixel uv_tgt (P, 2), the source it is
    read from src (P,) (an index into the sources) and its pixel there uv_src (P, 2)."""

    uv_tgt: F64
    src: I64
    uv_src: F64


@dataclass(frozen=True)
class Consistency:
    """Errors (N,) float64 of N candidates (RMS intensity difference, [0, 1] units) over
    `points` points (>= 1)."""

    errors: F64
    points: int


def subcell_pixels(grid_hw: tuple[int, int], image_hw: tuple[int, int],
                   per_side: int = PER_SIDE) -> F64:
    """Pixels (H, W, per_side^2, 2) (u, v) spread evenly over each cell of an (H, W) grid."""
    (gh, gw), (h, w) = grid_hw, image_hw
    offs = (np.arange(per_side) + 0.5) / per_side - 0.5  # fractions of a cell
    du, dv = np.meshgrid(offs * (w / gw), offs * (h / gh), indexing="xy")
    centres = cell_centres(grid_hw, image_hw)  # (H, W, 2)
    out: F64 = centres[:, :, None, :] + np.stack([du.ravel(), dv.ravel()], -1)[None, None]
    return out


def interior(uv: F64, image_hw: tuple[int, int]) -> npt.NDArray[np.bool_]:
    """Pixels (..., 2) where a bilinear read has its four neighbours: [0, w-1] x [0, h-1]."""
    h, w = image_hw
    u, v = uv[..., 0], uv[..., 1]
    out: npt.NDArray[np.bool_] = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    return out


def bilinear(image: npt.ArrayLike, uv: F64) -> F64:
    """Image (h, w, ch) read at interior pixels uv (P, 2) -> (P, ch) float64 (exact on an
    image linear in u and v)."""
    img = np.asarray(image, np.float64)
    h, w = img.shape[:2]
    u, v = np.clip(uv[:, 0], 0, w - 1), np.clip(uv[:, 1], 0, h - 1)
    u0 = np.minimum(np.floor(u), max(w - 2, 0)).astype(np.int64)
    v0 = np.minimum(np.floor(v), max(h - 2, 0)).astype(np.int64)
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    out: F64 = (img[v0, u0] * (1 - fu) * (1 - fv) + img[v0, u1] * fu * (1 - fv)
                + img[v1, u0] * (1 - fu) * fv + img[v1, u1] * fu * fv)
    return out


def reads(depth: F64, K_tgt: F64, T_tgt: F64, K_src: F64, T_src: F64, chosen: I64,
          image_hw: tuple[int, int], per_side: int = PER_SIDE) -> Reads:
    """The points of the supported cells that `chosen` (H, W) assigns a source (>= 0) and
    that land inside that source's image interior (module docstring).

    depth (H, W) m target packet depth (0 = no support); K_tgt (3, 3), T_tgt (4, 4)
    T_world_cam; K_src (S, 3, 3), T_src (S, 4, 4); image_hw the images' size (pixels)."""
    d = np.asarray(depth, np.float64)
    use = (d > 0) & np.isfinite(d) & (np.asarray(chosen) >= 0)
    uv = subcell_pixels(d.shape, image_hw, per_side)[use].reshape(-1, 2)  # (P, 2)
    src = np.repeat(np.asarray(chosen, np.int64)[use], per_side * per_side)
    z = np.repeat(d[use], per_side * per_side)
    # each point lifted at its cell's depth (z-depth, m) with the target camera
    K = np.asarray(K_tgt, np.float64)
    rays = np.concatenate([uv, np.ones_like(uv[:, :1])], -1) @ np.linalg.inv(K).T
    T = np.asarray(T_tgt, np.float64)
    X = (rays * z[:, None]) @ T[:3, :3].T + T[:3, 3]
    uv_src = np.full_like(uv, np.nan)
    for s in np.unique(src):
        m = src == s
        uv_src[m] = project(X[m], np.asarray(K_src)[s], np.asarray(T_src)[s])[0]
    ok = interior(uv_src, image_hw) & interior(uv, image_hw)
    return Reads(uv[ok], src[ok], uv_src[ok])


def image_consistency(candidates: npt.ArrayLike, src_images: npt.ArrayLike, at: Reads,
                      scale: float = 255.0) -> Consistency | None:
    """Errors of candidate target images (N, h, w, ch) against source images (S, h, w, ch)
    read at `at` (intensities / `scale`); None when no point is read (no score, never 0)."""
    if len(at.src) == 0:
        return None
    cand = np.asarray(candidates)
    srcs = np.asarray(src_images)
    ref = np.empty((len(at.src), srcs.shape[-1]))
    for s in np.unique(at.src):
        m = at.src == s
        ref[m] = bilinear(srcs[s], at.uv_src[m])
    errs = [np.sqrt(np.mean((bilinear(c, at.uv_tgt) - ref) ** 2)) / scale for c in cand]
    return Consistency(np.asarray(errs, np.float64), len(at.src))

