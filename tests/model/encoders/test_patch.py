"""The embedded `patch` image encoder: contract suite plus its exact decoder."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings

from model.encoders.patch import PATCH_DIM, PatchEncoder, orthonormal_map, unpatchify
from tests.model.encoders.contract import ImageEncoderContract, smooth_images
from tests.strategies import uint8_patch_images


class TestPatchEncoder(ImageEncoderContract):
    def make(self, seed: int) -> PatchEncoder:
        return PatchEncoder(channels=768, seed=seed)


class TestPatchEncoderPaperWidth(ImageEncoderContract):
    image_hw = (224, 336)
    batch = 2

    def make(self, seed: int) -> PatchEncoder:
        return PatchEncoder(channels=1536, seed=seed)


@pytest.mark.parametrize("channels", [588, 768, 1536])
def test_map_is_an_isometry(channels: int) -> None:
    q = orthonormal_map(channels, seed=3)
    assert q.shape == (PATCH_DIM, channels)
    np.testing.assert_allclose(q @ q.T, np.eye(PATCH_DIM), atol=1e-12)


def test_seeds_give_different_maps() -> None:
    assert not np.allclose(orthonormal_map(768, 0), orthonormal_map(768, 1))
    assert PatchEncoder(seed=0).weights_hash != PatchEncoder(seed=1).weights_hash


@settings(max_examples=25, deadline=None)
@given(uint8_patch_images())
def test_decode_inverts_encode_exactly(images: np.ndarray) -> None:
    enc = PatchEncoder(channels=768, seed=0)  # the map is cached per (channels, seed)
    np.testing.assert_array_equal(enc.decode(enc.encode(images)[0]), images)


def test_decode_exact_after_float16_storage() -> None:
    """The cache stores latents as float16; decoding them must stay within one grey level."""
    enc = PatchEncoder(channels=768, seed=0)
    images = smooth_images(2, (224, 336), seed=1)
    z16 = enc.encode(images)[0].astype(np.float16)
    err = np.abs(enc.decode(z16.astype(np.float32)).astype(int) - images.astype(int))
    assert err.max() <= 1


def test_decode_projects_off_subspace_latents() -> None:
    """A latent off the 588-d image subspace decodes like its orthogonal projection."""
    enc = PatchEncoder(channels=768, seed=0)
    images = smooth_images(1, (28, 28), seed=2)
    z = enc.encode(images)[0]
    null = np.random.default_rng(0).standard_normal(z.shape).astype(np.float32)
    rows = null.transpose(0, 2, 3, 1)                                # (1, h, w, C)
    null -= ((rows @ enc.q.T) @ enc.q).transpose(0, 3, 1, 2).astype(np.float32)
    np.testing.assert_array_equal(enc.decode(z + null), images)


def test_narrow_latent_decodes_to_the_min_norm_least_squares_image() -> None:
    enc = PatchEncoder(channels=64, seed=0)
    assert not enc.invertible
    np.testing.assert_allclose(enc.q.T @ enc.q, np.eye(64), atol=1e-12)
    images = smooth_images(1, (28, 28), seed=4)
    z = enc.encode(images)[0]                                     # (1, 64, 2, 2)
    rows = z.transpose(0, 2, 3, 1).reshape(-1, 64).T.astype(np.float64)  # (64, 4)
    v = np.linalg.lstsq(enc.q.T, rows, rcond=None)[0]              # (588, 4) min-norm
    expect = unpatchify(v.T.reshape(1, 2, 2, PATCH_DIM))
    decoded = enc.decode(z)
    assert not np.array_equal(decoded, images)
    assert np.abs(decoded.astype(int) - expect.astype(int)).max() <= 1


def test_decode_rejects_wrong_channels() -> None:
    with pytest.raises(ValueError, match="768"):
        PatchEncoder(channels=768).decode(np.zeros((1, 700, 2, 2), np.float32))
