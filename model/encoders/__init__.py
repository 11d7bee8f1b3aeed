"""Frozen encoders: image (patch, da3) and point (fpfh, utonia) behind one interface each."""

from model.encoders.base import (
    Float16Report,
    ImageDecoder,
    ImageEncoder,
    PointEncoder,
    float16_report,
)
from model.encoders.registry import (
    get_image_encoder,
    get_point_encoder,
    image_encoder_from_config,
    point_encoder_from_config,
)

__all__ = [
    "Float16Report",
    "ImageDecoder",
    "ImageEncoder",
    "PointEncoder",
    "float16_report",
    "get_image_encoder",
    "get_point_encoder",
    "image_encoder_from_config",
    "point_encoder_from_config",
]
