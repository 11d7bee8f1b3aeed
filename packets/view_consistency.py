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

from packets.projection import bilinear, in_image
from packets.reprojection import project, subcell_pixels
from packets.rigid import lift_pixels

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

PER_SIDE = 4
"""Points per cell side: 16 points per supported cell."""
INTERIOR_PX = 0.5
"""`in_image` margin of the image interior [0, w - 1] x [0, h - 1] where a bilinear read has
its four neighbours."""


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
    X = lift_pixels(uv, z, K_tgt, T_tgt)  # each point at its cell's depth, target camera
    uv_src = np.full_like(uv, np.nan)
    for s in np.unique(src):
        m = src == s
        uv_src[m] = project(X[m], np.asarray(K_src)[s], np.asarray(T_src)[s])[0]
    ok = in_image(uv_src, image_hw, INTERIOR_PX) & in_image(uv, image_hw, INTERIOR_PX)
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

