"""Camera messages to RGB pixels: sensor_msgs/Image (raw encodings) and CompressedImage (JPEG,
PNG). Pure functions of a message's fields; JPEG itself is decoded by `camera.strict_decode`.

Raw encodings (REP 104 / sensor_msgs/image_encodings.h names): rgb8, bgr8, rgba8, bgra8 (alpha
dropped), mono8, mono16 (grey to RGB), bayer_{rggb,bggr,gbrg,grbg}{8,16} (demosaiced by
OpenCV's bilinear `cvtColor`). A 16-bit image is scaled to 8 bits by its top byte (value >> 8:
0..65535 maps to 0..255, the full range of the type; no per-image stretching, so frames stay
comparable). Rows may be padded (`step` >= width x bytes per pixel); `is_bigendian` says the
byte order of 16-bit samples. An encoding outside this list raises UnsupportedImageError (not
damage: the data may be intact); a message whose size contradicts its own header (data shorter
than step x height, step shorter than a row) raises CorruptImageError.
"""

from __future__ import annotations

from typing import Any, Literal

import cv2
import numpy as np
import numpy.typing as npt

from pipeline.ingest.errors import CorruptImageError, UnsupportedImageError

U8 = npt.NDArray[np.uint8]

ImageKind = Literal["jpeg", "png", "raw"]

# encoding -> (channels, bytes per sample, cv2 conversion to RGB or None)
RAW_ENCODINGS: dict[str, tuple[int, int, int | None]] = {
    "rgb8": (3, 1, None),
    "bgr8": (3, 1, cv2.COLOR_BGR2RGB),
    "rgba8": (4, 1, cv2.COLOR_RGBA2RGB),
    "bgra8": (4, 1, cv2.COLOR_BGRA2RGB),
    "mono8": (1, 1, cv2.COLOR_GRAY2RGB),
    "mono16": (1, 2, cv2.COLOR_GRAY2RGB),
    # OpenCV names Bayer patterns by the second row's first two pixels: ROS rggb = cv2 BayerBG
    **{f"bayer_{p}{b}": (1, b // 8, code) for p, code in (
        ("rggb", cv2.COLOR_BayerBG2RGB), ("bggr", cv2.COLOR_BayerRG2RGB),
        ("gbrg", cv2.COLOR_BayerGR2RGB), ("grbg", cv2.COLOR_BayerGB2RGB)) for b in (8, 16)},
}  # fmt: skip
"""The raw encodings read, lower case (ROS writes them so; `8UC3` and others are refused)."""

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/Image")


def image_kind(msgtype: str, msg: Any, topic: str) -> ImageKind:
    """What a camera message holds: raw pixels, a PNG or a JPEG (UnsupportedImageError for a
    compressed format that is neither, e.g. compressedDepth or a video codec).

    A CompressedImage's `format` varies by driver ("jpeg", "jpg", "png", "bgr8; jpeg
    compressed bgr8", "rgb8; png compressed ..."); the PNG signature in the data decides
    between the two, an empty format is taken as JPEG (the data's markers then decide).
    """
    if msgtype in IMAGE_TYPES:
        encoding = str(msg.encoding).strip().lower()
        if encoding not in RAW_ENCODINGS:
            raise UnsupportedImageError(f"{topic}: image encoding {msg.encoding!r} is not "
                                        f"supported (supported: {', '.join(RAW_ENCODINGS)})")
        return "raw"
    fmt = str(getattr(msg, "format", "")).lower()
    head = bytes(np.asarray(msg.data[:8], dtype=np.uint8))
    if "compresseddepth" in fmt:
        raise UnsupportedImageError(f"{topic}: CompressedImage format {msg.format!r} (a depth "
                                    "image) is not a camera image m3gd reads")
    if head == PNG_MAGIC or "png" in fmt:
        return "png"
    if not fmt or "jpeg" in fmt or "jpg" in fmt:
        return "jpeg"
    raise UnsupportedImageError(f"{topic}: CompressedImage format {msg.format!r} is not "
                                "supported (JPEG and PNG are)")


def raw_to_rgb(msg: Any, where: str) -> U8:
    """(height, width, 3) uint8 RGB of a sensor_msgs/Image in a RAW_ENCODINGS encoding."""
    encoding = str(msg.encoding).strip().lower()
    channels, depth, code = RAW_ENCODINGS[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * depth
    data = np.asarray(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0:
        raise CorruptImageError(f"{where}: image of size {w}x{h}")
    if step < row or data.size < step * h:
        raise CorruptImageError(f"{where}: {encoding} image {w}x{h} needs rows of {row} bytes; "
                                f"step {step}, data {data.size} bytes (< step x height "
                                f"{step * h})")  # fmt: skip
    rows = data[: step * h].reshape(h, step)[:, :row]
    if depth == 2:
        dt = np.dtype(">u2" if bool(msg.is_bigendian) else "<u2")
        px = np.ascontiguousarray(rows).view(dt).reshape(h, w, channels)
        img = (px >> 8).astype(np.uint8)
    else:
        img = np.ascontiguousarray(rows).reshape(h, w, channels)
    if code is None:
        return np.ascontiguousarray(img)
    src = img[:, :, 0] if channels == 1 else img
    return np.asarray(cv2.cvtColor(np.ascontiguousarray(src), code), dtype=np.uint8)


def png_to_rgb(buf: U8, where: str) -> U8:
    """(height, width, 3) uint8 RGB of PNG bytes (16-bit scaled as raw images; alpha dropped).

    libpng checks every chunk's CRC: damaged data does not decode (CorruptImageError).
    """
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None:
        raise CorruptImageError(f"{where}: PNG data corrupt (does not decode)")
    if img.dtype == np.uint16:
        img = (np.asarray(img, dtype=np.uint16) >> 8).astype(np.uint8)
    if img.ndim == 2:
        return np.asarray(cv2.cvtColor(img, cv2.COLOR_GRAY2RGB), dtype=np.uint8)
    code = cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB
    return np.asarray(cv2.cvtColor(img, code), dtype=np.uint8)


def reduce_to(img: U8, hw: tuple[int, int]) -> U8:
    """`img` area-averaged to (h, w) (the raw counterpart of a reduced JPEG decode)."""
    if img.shape[:2] == hw:
        return img
    return np.asarray(cv2.resize(img, (hw[1], hw[0]), interpolation=cv2.INTER_AREA),
                      dtype=np.uint8)  # fmt: skip
