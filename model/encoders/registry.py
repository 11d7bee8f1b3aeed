"""Encoder registry: backend name -> class, imported only when asked for.

`get_image_encoder("patch", channels=768, seed=0)`; heavy backends (torch, DA3, Utonia)
are imported on first use, so the default embedded encoders never import them.
"""

from __future__ import annotations

import importlib
from typing import Any

from model.encoders.base import ImageEncoder, PointEncoder
from schemas.config import EncodersConfig
from schemas.errors import DataError

IMAGE_ENCODERS = {
    "patch": "model.encoders.patch:PatchEncoder",
    "da3": "model.encoders.da3:DA3Encoder",
}
POINT_ENCODERS = {
    "fpfh": "model.encoders.fpfh:FPFHEncoder",
    "utonia": "model.encoders.utonia:UtoniaEncoder",
}


def _load(table: dict[str, str], kind: str, name: str) -> Any:
    if name not in table:
        raise DataError(f"unknown {kind} encoder {name!r}; known: {sorted(table)}")
    module, cls = table[name].split(":")
    return getattr(importlib.import_module(module), cls)


def get_image_encoder(name: str, **opts: Any) -> ImageEncoder:
    """Build the image encoder `name` ('patch' or 'da3') with backend options `opts`."""
    enc: ImageEncoder = _load(IMAGE_ENCODERS, "image", name)(**opts)
    return enc


def get_point_encoder(name: str, **opts: Any) -> PointEncoder:
    """Build the point encoder `name` ('fpfh' or 'utonia') with backend options `opts`."""
    enc: PointEncoder = _load(POINT_ENCODERS, "point", name)(**opts)
    return enc


def image_encoder_from_config(cfg: EncodersConfig) -> ImageEncoder:
    """The configured image encoder (patch: image_channels, seed; da3: weights, flag, seed)."""
    if cfg.image == "patch":
        return get_image_encoder("patch", channels=cfg.image_channels, seed=cfg.seed)
    return get_image_encoder("da3", weights=cfg.da3_weights,
                             allow_random_init=cfg.allow_random_init, seed=cfg.seed,
                             device=cfg.device)


def point_encoder_from_config(cfg: EncodersConfig) -> PointEncoder:
    """The configured point encoder (fpfh: point_channels, seed; utonia: weights)."""
    if cfg.point == "fpfh":
        return get_point_encoder("fpfh", channels=cfg.point_channels, seed=cfg.seed)
    if cfg.utonia_weights is None:
        raise DataError("encoders.point = 'utonia' needs encoders.utonia_weights "
                         "(a local utonia.pth)")
    return get_point_encoder("utonia", weights=cfg.utonia_weights)
