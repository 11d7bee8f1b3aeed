"""The shared encoder interface: validation, counting and the float16 report."""

from __future__ import annotations

import numpy as np
import pytest

from model.encoders.base import ImageEncoder, PointEncoder, float16_report


class Broken(ImageEncoder):
    """Returns a NaN in its latent: the interface must refuse it."""

    name, version, weights_hash, pretrained, out_channels = "broken", "0", "x", False, 2
    levels = (0,)

    def _encode_image(self, image: np.ndarray) -> dict[int, np.ndarray]:
        z = np.zeros((2, image.shape[0] // 14, image.shape[1] // 14), np.float32)
        z[0, 0, 0] = np.nan
        return {0: z}


class WrongWidth(PointEncoder):
    name, version, weights_hash, pretrained, out_channels = "wrong", "0", "x", False, 4

    def _encode_sweep(self, xyz: np.ndarray, intensity: np.ndarray | None) -> np.ndarray:
        return np.zeros((len(xyz), 3), np.float32)


def test_non_finite_latents_are_refused() -> None:
    with pytest.raises(ValueError, match="broken level 0: 1 non-finite"):
        Broken().encode(np.zeros((1, 14, 14, 3), np.uint8))


def test_wrong_feature_width_is_refused() -> None:
    with pytest.raises(ValueError, match=r"expected shape \(5, 4\), got \(5, 3\)"):
        WrongWidth().encode(np.zeros((5, 3), np.float32))


def test_float16_report_known_values() -> None:
    x = np.array([70000.0, -1.0, 1.0 + 2.0**-12, 1e-9], np.float32)
    rep = float16_report(x)
    assert rep.max_abs == 70000.0 and rep.overflow == 1
    assert rep.max_rel_error == pytest.approx(2.0**-12 / (1 + 2.0**-12))
    assert float16_report(np.zeros(0)).overflow == 0
