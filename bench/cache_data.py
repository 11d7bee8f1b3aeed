"""The cache benchmark's sizes (`CacheBenchSpec`) and synthetic views (`make_views`): a leaf
the benchmark (`bench.cache_bench`) and its write timings (`bench.cache_write*`) import."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from schemas.cache_layout import GridSpec


@dataclass(frozen=True)
class CacheBenchSpec:
    """Sizes of the cache benchmark."""

    views: int = 256
    channels: int = 1536
    point_channels: int = 1224
    image_h: int = 224
    image_w: int = 336
    occupancy: float = 0.3
    shard_views: int = 64
    clips: int = 200
    clip_views: int = 4
    clip_span: int = 20
    seed: int = 0


def make_views(spec: CacheBenchSpec) -> dict[str, np.ndarray]:
    """Synthetic latents (N,C,H,W) f16, g (N,6,H,W) f32 and h (N,C_u,H,W) f16.

    h is a view of cell-major memory (N, H, W, C_u), as the packet stage's pooling leaves
    it (`packets.pooling`): the store packs its occupied rows without a transpose, and the
    `.npy` baseline saves each view's cells channels-last, as it has them."""
    rng = np.random.default_rng(spec.seed)
    grid = GridSpec(spec.image_h, spec.image_w)
    shape = (spec.views, 1, grid.grid_h, grid.grid_w)
    occupied = rng.random(shape) < spec.occupancy
    g = rng.normal(size=(spec.views, 6, grid.grid_h, grid.grid_w)).astype(np.float32) * occupied
    g[:, :1] = occupied  # the validity channel m (eq. 9)
    cells = (spec.views, grid.grid_h, grid.grid_w, spec.point_channels)
    h = np.moveaxis(np.where(occupied[:, 0, :, :, None],
                             rng.normal(size=cells).astype(np.float16), np.float16(0)), -1, 1)
    lat = rng.normal(size=(spec.views, spec.channels, grid.grid_h, grid.grid_w)).astype(np.float16)
    return {"latents_l0": lat, "g": g, "h": h}
