"""Per camera: image topic and type, encoding or format, image size, frame, and the
calibration (CameraInfo) sampled across the recording, with any change of it.

An image topic (`sensor_msgs/Image` or `CompressedImage`) is paired with the CameraInfo topic
of the longest common namespace (`/cam/image_raw/compressed` with `/cam/camera_info`).
Compressed images are decoded (a few) for their size; the format is the message's `format`
string and the payload's magic bytes (JPEG, PNG).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from pipeline.ingest.sources.bags import BagFile, stamp_ns
from pipeline.inspect import sample
from pipeline.inspect.model import Calibration, CameraReport
from schemas.errors import DataError

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
IMAGES_SAMPLED = 3
"""Images decoded per camera (from the first)."""
INFOS_SAMPLED = 5
"""CameraInfo messages read per camera, spread evenly over its log times."""


def namespace(topic: str) -> str:
    """The topic without its last name (`/a/b/c` -> `/a/b`)."""
    return topic.rstrip("/").rsplit("/", 1)[0]


def pair_info(image_topic: str, infos: list[str]) -> str | None:
    """The CameraInfo topic whose namespace is the longest prefix of `image_topic`'s path."""
    parts = image_topic.strip("/").split("/")
    best, best_len = None, 0
    for info in infos:
        ns = namespace(info).strip("/").split("/")
        if ns and parts[: len(ns)] == ns and len(ns) > best_len:
            best, best_len = info, len(ns)
    return best


def magic(data: bytes) -> str:
    """The container of compressed image bytes: jpeg, png or unknown."""
    if data[:3] == b"\xff\xd8\xff":
        return "jpeg"
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "png"
    return "unknown"


def image_facts(msgtype: str, msg: Any) -> tuple[str, tuple[int, int] | None]:
    """(encoding or format, (width, height)) of one image message (size None: undecodable)."""
    if msgtype.endswith("CompressedImage"):
        data = np.asarray(msg.data, dtype=np.uint8)
        kind = magic(data[:8].tobytes())
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if kind != "unknown" else None
        size = None if img is None else (int(img.shape[1]), int(img.shape[0]))
        return f"{msg.format or '(no format)'} ({kind})", size
    return str(msg.encoding), (int(msg.width), int(msg.height))


def calibration(msg: Any) -> Calibration:
    """The facts of one CameraInfo (K row-major: fx K[0], fy K[4], cx K[2], cy K[5])."""
    k = [float(v) for v in np.asarray(msg.K if hasattr(msg, "K") else msg.k, np.float64)]
    d = np.asarray(msg.D if hasattr(msg, "D") else msg.d)
    return Calibration(stamp_ns(msg), str(msg.distortion_model), int(d.size), int(msg.width),
                       int(msg.height), k[0], k[4], k[2], k[5])  # fmt: skip


def changes(cals: tuple[Calibration, ...]) -> bool:
    """Whether the sampled calibrations differ in model, size or intrinsics."""
    keys = {(c.distortion_model, c.n_coefficients, c.width, c.height, c.fx, c.fy, c.cx, c.cy)
            for c in cals}  # fmt: skip
    return len(keys) > 1


def spread(times: np.ndarray | None, n: int) -> list[int]:
    """Up to `n` log times spread evenly over `times` (first and last included)."""
    if times is None or times.size == 0:
        return []
    idx = np.unique(np.linspace(0, times.size - 1, min(n, times.size)).round().astype(int))
    return [int(times[i]) for i in idx]


def camera_report(bags: list[BagFile], image_topic: str, msgtype: str, info_topic: str | None,
                  info_times: np.ndarray | None) -> CameraReport:  # fmt: skip
    """Encoding, sizes and frame of the first images; calibrations spread over the recording."""
    encodings, sizes, frame, error, info_frame = [], [], "", None, ""
    try:
        for _, msg in sample.first(bags, image_topic, IMAGES_SAMPLED):
            enc, size = image_facts(msgtype, msg)
            frame = frame or str(msg.header.frame_id)
            encodings.append(enc)
            if size is not None and size not in sizes:
                sizes.append(size)
        cals: list[Calibration] = []
        if info_topic is not None:
            for t in spread(info_times, INFOS_SAMPLED):
                got = sample.at(bags, info_topic, t)
                if got is not None:
                    cals.append(calibration(got[1]))
                    info_frame = info_frame or str(got[1].header.frame_id)
    except DataError as err:
        error, cals = str(err), []
    encoding = ", ".join(dict.fromkeys(encodings)) or "(no image read)"
    return CameraReport(image_topic, msgtype, info_topic, frame, encoding, tuple(sizes),
                        tuple(cals), changes(tuple(cals)), error, info_frame)  # fmt: skip
