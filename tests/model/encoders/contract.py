"""Contract tests every encoder backend passes (subclass, like zarr's StoreTests).

A backend test module subclasses `ImageEncoderContract` or `PointEncoderContract` as
`Test<Backend>` and implements `make(seed)`; sizes are class attributes so slow backends
(DA3 on CPU) run with one or two images.
"""

from __future__ import annotations

import numpy as np
import pytest

from model.encoders.base import ImageEncoder, PointEncoder, float16_report
from schemas.cache_layout import F16_MAX

FP16_REL = 2.0**-11  # float16 round-to-nearest relative error bound


def smooth_images(n: int, hw: tuple[int, int], seed: int) -> np.ndarray:
    """uint8 (n, H, W, 3): random colour gradients plus noise, distinct per image."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:hw[0], 0:hw[1]] / max(hw)
    out = np.empty((n, *hw, 3), np.uint8)
    for i in range(n):
        a = rng.uniform(-200, 200, (3, 3))
        base = a[0] * yy[..., None] + a[1] * xx[..., None] + rng.uniform(0, 255, 3)
        out[i] = np.clip(base + rng.normal(0, 20, (*hw, 3)), 0, 255).astype(np.uint8)
    return out


class ImageEncoderContract:
    """Shapes, dtypes, finiteness, determinism, batch invariance, counting, float16 range."""

    image_hw: tuple[int, int] = (28, 42)
    batch: int = 3

    def make(self, seed: int) -> ImageEncoder:
        raise NotImplementedError

    @pytest.fixture(scope="class")
    def encoder(self) -> ImageEncoder:
        return self.make(0)

    @pytest.fixture(scope="class")
    def images(self) -> np.ndarray:
        return smooth_images(self.batch, self.image_hw, seed=7)

    @pytest.fixture(scope="class")
    def encoded(self, encoder: ImageEncoder, images: np.ndarray) -> dict[int, np.ndarray]:
        return encoder.encode(images)

    def test_shapes_and_dtypes(self, encoder: ImageEncoder, encoded: dict) -> None:
        h, w = self.image_hw[0] // encoder.patch, self.image_hw[1] // encoder.patch
        assert sorted(encoded) == sorted(encoder.levels)
        for z in encoded.values():
            assert z.shape == (self.batch, encoder.out_channels, h, w)
            assert z.dtype == np.float32

    def test_finite_and_not_constant(self, encoded: dict) -> None:
        for z in encoded.values():
            assert np.isfinite(z).all()
            assert not np.array_equal(z[0], z[-1]), "different images, same latent"
            assert z.std() > 0

    def test_deterministic_across_instances(self, images: np.ndarray, encoded: dict) -> None:
        again = self.make(0).encode(images[:1])
        for lv, z in encoded.items():
            np.testing.assert_array_equal(again[lv][0], z[0])

    def test_batch_invariant(self, encoder: ImageEncoder, images: np.ndarray,
                             encoded: dict) -> None:
        for i in range(self.batch):
            alone = encoder.encode(images[i:i + 1])
            for lv, z in encoded.items():
                np.testing.assert_array_equal(alone[lv][0], z[i])

    def test_counts_images(self, images: np.ndarray) -> None:
        enc = self.make(0)
        assert enc.n_encoded == 0
        enc.encode(images[:1])
        assert enc.n_encoded == 1

    def test_identity(self, encoder: ImageEncoder) -> None:
        ident = encoder.identity()
        assert ident.name == encoder.name and ident.channels == encoder.out_channels
        assert isinstance(ident.pretrained, bool) and ident.weights_hash and ident.version

    def test_rejects_bad_images(self, encoder: ImageEncoder, images: np.ndarray) -> None:
        with pytest.raises(TypeError, match="uint8"):
            encoder.encode(images.astype(np.float32))
        with pytest.raises(ValueError, match="multiple"):
            encoder.encode(images[:, :-1])

    def test_float16_range(self, encoded: dict) -> None:
        for lv, z in encoded.items():
            rep = float16_report(z)
            print(f"{type(self).__name__} level {lv}: {rep}")
            assert rep.overflow == 0 and rep.max_abs < F16_MAX
            assert rep.max_rel_error <= FP16_REL


class PointEncoderContract:
    """Shapes, dtypes, finiteness, empty/tiny sweeps, determinism, equivariance, counting."""

    def make(self, seed: int) -> PointEncoder:
        raise NotImplementedError

    def sweep(self) -> tuple[np.ndarray, np.ndarray | None]:
        """A small real sweep: xyz (N, 3) float32 metres, intensity (N,) or None."""
        raise NotImplementedError

    @pytest.fixture(scope="class")
    def encoder(self) -> PointEncoder:
        return self.make(0)

    @pytest.fixture(scope="class")
    def points(self) -> tuple[np.ndarray, np.ndarray | None]:
        return self.sweep()

    @pytest.fixture(scope="class")
    def encoded(self, encoder: PointEncoder, points: tuple) -> np.ndarray:
        return encoder.encode(*points)

    def test_shape_dtype_finite(self, encoder: PointEncoder, points: tuple,
                                encoded: np.ndarray) -> None:
        assert encoded.shape == (len(points[0]), encoder.out_channels)
        assert encoded.dtype == np.float32 and np.isfinite(encoded).all()
        assert encoded.std(axis=0).max() > 0, "features do not vary over points"

    @pytest.mark.parametrize("n", [0, 1, 2, 3, 7])
    def test_empty_and_tiny_sweeps(self, encoder: PointEncoder, points: tuple, n: int) -> None:
        xyz, inten = points
        out = encoder.encode(xyz[:n], None if inten is None else inten[:n])
        assert out.shape == (n, encoder.out_channels) and np.isfinite(out).all()

    def test_deterministic_across_instances(self, points: tuple, encoded: np.ndarray) -> None:
        np.testing.assert_array_equal(self.make(0).encode(*points), encoded)

    def test_stateless(self, encoder: PointEncoder, points: tuple, encoded: np.ndarray) -> None:
        xyz, inten = points
        encoder.encode(xyz[::-2] + 3.0, None)
        np.testing.assert_array_equal(encoder.encode(xyz, inten), encoded)

    def test_permutation_equivariant(self, encoder: PointEncoder, points: tuple,
                                     encoded: np.ndarray) -> None:
        xyz, inten = points
        perm = np.random.default_rng(3).permutation(len(xyz))
        out = encoder.encode(xyz[perm], None if inten is None else inten[perm])
        np.testing.assert_allclose(out, encoded[perm], atol=1e-4)

    def test_counts_sweeps(self, points: tuple) -> None:
        enc = self.make(0)
        enc.encode(*points)
        enc.encode(points[0][:0], None)
        assert enc.n_encoded == 2

    def test_rejects_bad_sweeps(self, encoder: PointEncoder, points: tuple) -> None:
        xyz = points[0].copy()
        with pytest.raises(ValueError, match=r"\(N, 3\)"):
            encoder.encode(xyz[:, :2])
        xyz[1, 2] = np.nan
        with pytest.raises(ValueError, match="index 1"):
            encoder.encode(xyz)
        with pytest.raises(ValueError, match="intensity"):
            encoder.encode(points[0], np.zeros(len(xyz) + 1, np.float32))

    def test_float16_range(self, encoded: np.ndarray) -> None:
        rep = float16_report(encoded)
        print(f"{type(self).__name__}: {rep}")
        assert rep.overflow == 0 and rep.max_rel_error <= FP16_REL
