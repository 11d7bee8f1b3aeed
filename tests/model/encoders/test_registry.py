"""Encoder registry and construction from the config."""

from __future__ import annotations

import subprocess
import sys

import pytest

from model.encoders import (
    get_image_encoder,
    get_point_encoder,
    image_encoder_from_config,
    point_encoder_from_config,
)
from model.encoders.fpfh import FPFHEncoder
from model.encoders.patch import PatchEncoder
from schemas.config import EncodersConfig


def test_names_resolve_to_backends() -> None:
    enc = get_image_encoder("patch", channels=600, seed=2)
    assert isinstance(enc, PatchEncoder) and enc.out_channels == 600 and enc.seed == 2
    assert isinstance(get_point_encoder("fpfh", channels=8), FPFHEncoder)


def test_unknown_names_list_the_known_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown image encoder 'vit'.*'da3', 'patch'"):
        get_image_encoder("vit")
    with pytest.raises(ValueError, match=r"unknown point encoder 'pointnet'.*'fpfh'"):
        get_point_encoder("pointnet")


def test_default_config_builds_the_embedded_encoders() -> None:
    cfg = EncodersConfig()
    img, pts = image_encoder_from_config(cfg), point_encoder_from_config(cfg)
    assert (img.name, img.out_channels, img.pretrained) == ("patch", cfg.image_channels, False)
    assert (pts.name, pts.out_channels) == ("fpfh", cfg.point_channels)


def test_config_for_real_encoders_without_weights_is_refused() -> None:
    with pytest.raises(ValueError, match="allow_random_init"):
        image_encoder_from_config(EncodersConfig(image="da3"))
    with pytest.raises(ValueError, match="utonia_weights"):
        point_encoder_from_config(EncodersConfig(point="utonia"))


def test_embedded_encoders_do_not_import_torch() -> None:
    code = ("import sys; from model.encoders import get_image_encoder, get_point_encoder; "
            "get_image_encoder('patch'); get_point_encoder('fpfh'); "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
