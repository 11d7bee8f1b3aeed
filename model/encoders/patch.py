"""Embedded image encoder `patch`: a fixed orthonormal linear map of 14x14 RGB patches.

Not a learned encoder: it needs no weights, and exists so that the pipeline, the cache and
the trainer run end to end without Depth Anything 3 weights, and so that generated latents
can be judged by the PSNR of their decoded images.

Each 14x14x3 patch, flattened in (row, col, rgb) order to v in R^588 with values
x / 127.5 - 1 in [-1, 1], maps to z = Q^T v in R^C, where Q (588, C) comes from the QR
decomposition of a seeded Gaussian matrix. For C >= 588 the map is an isometry onto a
588-dimensional subspace (Q Q^T = I_588), so `decode` (v = Q z) inverts it exactly up to
uint8 rounding; a generated latent off that subspace decodes to its orthogonal projection.
For C < 588 the decoder is the least-squares projection and is lossy (`invertible` False).
Every latent entry satisfies |z_i| <= ||v|| <= sqrt(588) ~ 24.2, far inside float16.

Default C = 768: the smallest common transformer width >= 588 (the exactness bound), half
of DA3's 1536 so the cache is half the size; C = 1536 gives DA3's shape and is as exact.
"""

from __future__ import annotations

import functools
import hashlib

import numpy as np

from model.encoders.base import PATCH, ImageDecoder, ImageEncoder, check_latent
from schemas.errors import DataError

PATCH_DIM = PATCH * PATCH * 3
"""Values per RGB patch (588)."""


@functools.lru_cache(maxsize=8)
def orthonormal_map(channels: int, seed: int) -> np.ndarray:
    """Seeded (588, C) float64 matrix whose min(588, C) columns / rows are orthonormal.

    C >= 588: rows orthonormal (Q Q^T = I_588). C < 588: columns orthonormal (Q^T Q = I_C).
    Signs fixed by the QR convention diag(R) > 0 so the result is unique for a seed.
    Cached per (channels, seed) and returned read-only.
    """
    if channels < 1:
        raise DataError(f"patch encoder: channels must be >= 1, got {channels}")
    g = np.random.default_rng(seed).standard_normal((max(channels, PATCH_DIM),
                                                     min(channels, PATCH_DIM)))
    q, r = np.linalg.qr(g)
    q = q * np.sign(np.diag(r))[None, :]
    q = np.ascontiguousarray(q.T if channels >= PATCH_DIM else q)
    q.flags.writeable = False
    return q


def patchify(image: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) -> float64 (H/14, W/14, 588) in [-1, 1], (row, col, rgb) order."""
    h, w = image.shape[0] // PATCH, image.shape[1] // PATCH
    p = image.reshape(h, PATCH, w, PATCH, 3).transpose(0, 2, 1, 3, 4)
    return p.reshape(h, w, PATCH_DIM).astype(np.float64) / 127.5 - 1.0


def unpatchify(v: np.ndarray) -> np.ndarray:
    """float (B, h, w, 588) in [-1, 1] -> uint8 (B, 14h, 14w, 3), rounded and clipped."""
    b, h, w, _ = v.shape
    x = np.clip(np.rint((v + 1.0) * 127.5), 0, 255).astype(np.uint8)
    x = x.reshape(b, h, w, PATCH, PATCH, 3).transpose(0, 1, 3, 2, 4, 5)
    return np.ascontiguousarray(x.reshape(b, h * PATCH, w * PATCH, 3))


class PatchEncoder(ImageEncoder, ImageDecoder):
    """Fixed orthonormal patch map (see module doc); one level (0) of C channels."""

    name = "patch"
    version = "1"
    pretrained = False

    def __init__(self, channels: int = 768, seed: int = 0) -> None:
        super().__init__()
        self.out_channels = int(channels)
        self.levels = (0,)
        self.seed = int(seed)
        self.q = orthonormal_map(self.out_channels, self.seed)  # (588, C) float64
        self.invertible = self.out_channels >= PATCH_DIM
        key = f"patch v{self.version} seed={self.seed} C={self.out_channels} scale=x/127.5-1"
        self.weights_hash = hashlib.sha256(key.encode()).hexdigest()[:16]

    def _encode_image(self, image: np.ndarray) -> dict[int, np.ndarray]:
        v = patchify(image)                          # (h, w, 588)
        z = v @ self.q                               # (h, w, C)
        return {0: z.transpose(2, 0, 1).astype(np.float32)}  # (C, h, w)

    def decode(self, latent: np.ndarray) -> np.ndarray:
        """Latent (B, C, h, w) float -> uint8 images (B, 14h, 14w, 3); exact for C >= 588."""
        latent = np.asarray(latent)
        if latent.ndim != 4 or latent.shape[1] != self.out_channels:
            raise DataError(f"patch decoder: latent must be (B, {self.out_channels}, h, w), "
                             f"got {latent.shape}")
        z = check_latent(latent, latent.shape, "patch decoder latent").astype(np.float64)
        v = z.transpose(0, 2, 3, 1) @ self.q.T       # (B, h, w, 588)
        return unpatchify(v)
