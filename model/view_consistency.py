"""Reprojection consistency of a synthesized target view (pure math, no I/O).

The paper scores a synthesized view's geometry by its "3D reprojection error". With the
embedded encoders there is no depth readout of a synthesized latent (docs/benchmarks_model.md,
"Reprojection consistency of synthesized views"), so the geometry is scored through the LiDAR
points the target was conditioned on: every target cell with LiDAR support (its packet depth)
is lifted, projected into the clip's source views and the source latent read there
(`model.reprojection.warp_latents`, nearest cell, visibility by depth order). On the cells
some source fills, a candidate target latent is compared with that reprojection:

    err = sqrt( mean over filled cells (i, j) and channels c of (z[c, i, j] - w[c, i, j])^2 )

in the units of the latents handed in (the scoring loop hands in latents normalized per
channel by the cache's statistics, so `err` is in cache standard deviations). A candidate
equal to the reprojection scores exactly 0. The ground-truth target does not: occlusions the
coarse cell depth misses, view-dependent appearance and the cell-centre sampling leave a
floor; a model consistent with the LiDAR geometry scores near that floor, one that ignores
it scores near a baseline that ignores it (copy the nearest source, the mean latent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model.reprojection import REL_TOL, Sampling, Warp, warp_latents

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class Consistency:
    """Errors of N candidates against one target's reprojection.

    errors: (N,) float64 root-mean-square difference over the filled cells and channels
    (latent units); cells: how many target cells a source filled (>= 1).
    """

    errors: F64
    cells: int


def masked_rms(candidates: npt.ArrayLike, reference: npt.ArrayLike,
               mask: npt.ArrayLike) -> F64:
    """Root-mean-square difference (N,) of candidates (N, C, H, W) from reference (C, H, W)
    over the cells of mask (H, W) and every channel, in float64.

    ValueError when the mask selects no cell (the error is undefined there, never 0)."""
    cand = np.asarray(candidates, np.float64)
    ref = np.asarray(reference, np.float64)
    m = np.asarray(mask, bool)
    if cand.ndim != 4 or cand.shape[1:] != ref.shape or ref.shape[1:] != m.shape:
        raise ValueError(f"candidates {cand.shape}, reference {ref.shape} and mask {m.shape} "
                         "must be (N, C, H, W), (C, H, W) and (H, W)")
    if not m.any():
        raise ValueError("masked_rms: the mask selects no cell")
    diff = cand[:, :, m] - ref[None, :, m]  # (N, C, cells)
    out: F64 = np.sqrt(np.mean(diff * diff, axis=(1, 2)))
    return out


def consistency_of(candidates: npt.ArrayLike, warp: Warp) -> Consistency | None:
    """Errors of candidates (N, C, H, W) against a target's reprojection `warp` (latent
    (C, H, W), valid (H, W)); None when no cell was filled (no LiDAR support any source
    sees: the target has no score, never a 0)."""
    if not warp.valid.any():
        return None
    return Consistency(masked_rms(candidates, warp.latent, warp.valid), int(warp.valid.sum()))


def reprojection_consistency(candidates: npt.ArrayLike, src_latents: F64, depth: F64,
                             K_tgt: F64, T_tgt: F64, K_src: F64, T_src: F64, src_depth: F64,
                             image_hw: tuple[int, int], mode: Sampling = "nearest",
                             rel_tol: float = REL_TOL) -> Consistency | None:
    """Errors of candidate target latents (N, C, H, W) against the reprojection of the
    sources into the target (module docstring).

    src_latents (S, C, H, W); depth (H, W) target packet depth (m, 0 = no support); K_tgt
    (3, 3), T_tgt (4, 4) T_world_cam; K_src (S, 3, 3), T_src (S, 4, 4); src_depth (S, H, W)
    m; image_hw the image size the K refer to (pixels). None where no cell is filled.
    """
    w = warp_latents(src_latents, depth, K_tgt, T_tgt, K_src, T_src, src_depth, image_hw,
                     mode, rel_tol)
    return consistency_of(candidates, w)
