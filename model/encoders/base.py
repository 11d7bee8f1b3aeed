"""One interface for frozen image encoders and one for frozen point encoders.

Every backend subclasses `ImageEncoder` or `PointEncoder` and implements one private method
on a single input (`_encode_image`, `_encode_sweep`); the public `encode` validates the input,
calls it once per image / per sweep, checks the output and counts the calls (`n_encoded`),
so the cache stage can assert that every image and every sweep is encoded exactly once.
"""

from __future__ import annotations

import abc
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from schemas.cache_layout import F16_MAX, EncoderIdentity
from schemas.errors import DataError

PATCH = 14
"""Image-latent patch size in pixels (DINOv2 / DA3 patch; 224x336 -> 16x24 cells)."""



class ImageEncoder(abc.ABC):
    """Frozen image encoder: uint8 images (B, H, W, 3) -> latent levels (B, C, H/14, W/14).

    Each image is encoded alone, so a latent depends on its own image only and encoding a
    batch equals encoding each image alone (a backend may run the batch through its network
    at once, `_encode_batch`, as long as images do not interact). `n_encoded` counts the
    images encoded so far.
    """

    name: str
    version: str
    weights_hash: str
    pretrained: bool
    out_channels: int
    levels: tuple[int, ...]
    patch: int = PATCH

    def __init__(self) -> None:
        self.n_encoded = 0

    def encode(self, images: np.ndarray) -> dict[int, np.ndarray]:
        """Encode uint8 RGB images (B, H, W, 3), H and W multiples of `patch`.

        Returns {level: float32 (B, C, H/patch, W/patch)} for every level in `levels`.
        """
        check_images(images, self.patch, self.name)
        b, h, w, _ = images.shape
        shape = (b, self.out_channels, h // self.patch, w // self.patch)
        levels = self._encode_batch(images)
        self.n_encoded += b
        return {lv: check_latent(levels[lv], shape, f"{self.name} level {lv}")
                for lv in self.levels}

    def _encode_batch(self, images: np.ndarray) -> dict[int, np.ndarray]:
        """Encode uint8 images (B, H, W, 3) -> {level: (B, C, H/patch, W/patch)}; by default
        one `_encode_image` call per image."""
        ones = [self._encode_image(im) for im in images]
        return {lv: np.stack([one[lv] for one in ones]) for lv in self.levels}

    @abc.abstractmethod
    def _encode_image(self, image: np.ndarray) -> dict[int, np.ndarray]:
        """Encode one uint8 image (H, W, 3) -> {level: float32 (C, H/patch, W/patch)}."""

    def identity(self) -> EncoderIdentity:
        """Name, version, weights hash, pretrained flag and channels for cache metadata."""
        return EncoderIdentity(self.name, self.version, self.weights_hash, self.pretrained,
                               self.out_channels)


class ImageDecoder(abc.ABC):
    """Exact or least-squares inverse of an image encoder's level-0 latent."""

    @abc.abstractmethod
    def decode(self, latent: np.ndarray) -> np.ndarray:
        """Latent float (B, C, h, w) -> uint8 images (B, h*patch, w*patch, 3)."""


class PointEncoder(abc.ABC):
    """Frozen point encoder: one sweep (N, 3) metres in the LiDAR frame -> (N, C_u) float32.

    `n_encoded` counts the sweeps encoded so far.
    """

    name: str
    version: str
    weights_hash: str
    pretrained: bool
    out_channels: int

    def __init__(self) -> None:
        self.n_encoded = 0

    def encode(self, xyz: np.ndarray, intensity: np.ndarray | None = None) -> np.ndarray:
        """Per-point features float32 (N, C_u) of a sweep; N = 0 gives (0, C_u).

        xyz: (N, 3) float32 metres in the LiDAR frame; intensity: (N,) float32 or None.
        """
        xyz, intensity = check_sweep(xyz, intensity, self.name)
        feat = self._encode_sweep(xyz, intensity)
        self.n_encoded += 1
        return check_latent(feat, (xyz.shape[0], self.out_channels), f"{self.name} features")

    @abc.abstractmethod
    def _encode_sweep(self, xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        """Encode one validated sweep -> float32 (N, C_u)."""

    def identity(self) -> EncoderIdentity:
        """Name, version, weights hash, pretrained flag and channels for cache metadata."""
        return EncoderIdentity(self.name, self.version, self.weights_hash, self.pretrained,
                               self.out_channels)


def check_images(images: np.ndarray, patch: int, who: str) -> None:
    """Refuse anything but uint8 (B, H, W, 3) with H, W positive multiples of `patch`."""
    if not isinstance(images, np.ndarray) or images.dtype != np.uint8:
        raise TypeError(f"{who}: images must be a uint8 numpy array, got "
                        f"{type(images).__name__} {getattr(images, 'dtype', None)}")
    if images.ndim != 4 or images.shape[3] != 3:
        raise DataError(f"{who}: images must be (B, H, W, 3), got shape {images.shape}")
    h, w = images.shape[1:3]
    if h == 0 or w == 0 or h % patch or w % patch:
        raise DataError(f"{who}: image size {h}x{w} is not a positive multiple of the "
                         f"{patch} px patch")


def check_sweep(xyz: np.ndarray, intensity: np.ndarray | None,
                who: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Validate a sweep; return float32 xyz (N, 3) and float32 intensity (N,) or None."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise DataError(f"{who}: xyz must be (N, 3), got shape {xyz.shape}")
    xyz = xyz.astype(np.float32, copy=False)
    if not np.isfinite(xyz).all():
        bad = int(np.flatnonzero(~np.isfinite(xyz).all(axis=1))[0])
        raise DataError(f"{who}: xyz has a non-finite point at index {bad}: {xyz[bad]}")
    if intensity is None:
        return xyz, None
    intensity = np.asarray(intensity).astype(np.float32, copy=False)
    if intensity.shape != (xyz.shape[0],):
        raise DataError(f"{who}: intensity must be ({xyz.shape[0]},), got {intensity.shape}")
    if not np.isfinite(intensity).all():
        raise DataError(f"{who}: intensity has non-finite values")
    return xyz, intensity


def check_latent(x: np.ndarray, shape: tuple[int, ...], what: str) -> np.ndarray:
    """Refuse an encoder output of the wrong shape or with NaN/Inf; return it as float32."""
    x = np.asarray(x, dtype=np.float32)
    if x.shape != tuple(shape):
        raise DataError(f"{what}: expected shape {tuple(shape)}, got {x.shape}")
    if not np.isfinite(x).all():
        raise DataError(f"{what}: {int((~np.isfinite(x)).sum())} non-finite values")
    return x


@dataclass(frozen=True)
class Float16Report:
    """How well float32 values survive a float16 cast."""

    max_abs: float
    overflow: int
    """Count of finite float32 values beyond the float16 range (become Inf)."""
    max_rel_error: float
    """Max |x16 - x| / |x| over values with |x| >= the smallest normal float16."""


def float16_report(x: np.ndarray) -> Float16Report:
    """Range and precision of float32 values `x` (any shape) after a float16 cast."""
    x = np.asarray(x, dtype=np.float32).ravel()
    if x.size == 0:
        return Float16Report(0.0, 0, 0.0)
    ax = np.abs(x)
    over = ax > F16_MAX
    normal = (ax >= np.finfo(np.float16).tiny) & ~over
    with np.errstate(over="ignore"):
        x16 = x.astype(np.float16).astype(np.float32)
    rel = np.abs(x16[normal] - x[normal]) / ax[normal]
    return Float16Report(float(ax.max()), int(over.sum()),
                         float(rel.max()) if rel.size else 0.0)


def file_sha256(path: Path, chunk: int = 1 << 24) -> str:
    """Hex SHA-256 of a file's bytes (weights identity for the cache key)."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()
