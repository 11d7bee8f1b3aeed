"""Measure the decode choices: JPEG reduction x map precision, time and error vs a reference.

The reference is the plain three-step chain: full-size decode, fisheye undistortion at the raw
size, then centre crop and an area-averaging resize to the output size. Each one-remap choice is
timed per image (process CPU time) and scored by PSNR (dB, over uint8 RGB) against that reference.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import cv2
import numpy as np
import numpy.typing as npt

from pipeline.ingest.calib.camera import (
    REDUCE_FLAGS,
    RawCamera,
    build_rectifier,
    choose_reduction,
    output_K,
    rectified_K,
)
from schemas.errors import DataError

U8 = npt.NDArray[np.uint8]


def reference_rectify(jpeg: bytes, cam: RawCamera, out_hw: tuple[int, int], balance: float) -> U8:
    """(out_h, out_w, 3) RGB by full decode, full-size undistortion, crop and INTER_AREA resize."""
    bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DataError("reference_rectify: JPEG does not decode")
    K_rect = rectified_K(cam, balance)
    size = (cam.width, cam.height)
    if cam.model == "equidistant":
        mx, my = cv2.fisheye.initUndistortRectifyMap(
            cam.K, cam.D.reshape(1, 4), np.eye(3), K_rect, size, cv2.CV_32FC1
        )
    else:
        mx, my = cv2.initUndistortRectifyMap(cam.K, cam.D, np.eye(3), K_rect, size, cv2.CV_32FC1)
    full = cv2.remap(bgr, mx, my, cv2.INTER_LINEAR)
    (h, w), (oh, ow) = (cam.height, cam.width), out_hw
    crop_w, crop_h = (h * ow / oh, h) if w * oh > ow * h else (w, w * oh / ow)
    x0, y0 = round((w - crop_w) / 2), round((h - crop_h) / 2)
    crop = full[y0 : y0 + round(crop_h), x0 : x0 + round(crop_w)]
    out = cv2.resize(crop, (ow, oh), interpolation=cv2.INTER_AREA)
    return np.asarray(cv2.cvtColor(out, cv2.COLOR_BGR2RGB), dtype=np.uint8)


def psnr(a: U8, b: U8, border: int = 2) -> float:
    """PSNR in dB between two uint8 images, ignoring `border` pixels at each edge."""
    sl = (slice(border, -border or None), slice(border, -border or None))
    err = np.mean((a[sl].astype(np.float64) - b[sl].astype(np.float64)) ** 2)
    return float("inf") if err == 0 else float(10 * np.log10(255.0**2 / err))


@dataclass(frozen=True)
class DecodeChoice:
    """One decode choice: reduction r, map precision, ms per image, PSNR dB, chosen by default."""

    reduction: int
    fixed_point: bool
    ms_per_image: float
    psnr_db: float
    default: bool


def measure_choices(
    jpegs: Sequence[bytes], cam: RawCamera, out_hw: tuple[int, int], balance: float = 0.0
) -> list[dict[str, object]]:
    """Time and PSNR of every reduction (1, 2, 4, 8) x map precision on the same images."""
    refs = [reference_rectify(j, cam, out_hw, balance) for j in jpegs]
    default_r = choose_reduction(cam, output_K(cam, out_hw, balance), True)
    rows = []
    for r in REDUCE_FLAGS:
        for fixed in (True, False):
            rect = build_rectifier(cam, out_hw, balance, reduction=r, fixed_point=fixed)
            rect.apply(jpegs[0], "warm-up")
            t0 = time.process_time()
            outs = [rect.apply(j, "bench") for j in jpegs]
            ms = (time.process_time() - t0) * 1e3 / max(len(jpegs), 1)
            score = float(np.mean([psnr(o, ref) for o, ref in zip(outs, refs, strict=True)]))
            choice = DecodeChoice(r, fixed, ms, score, r == default_r and fixed)
            rows.append(asdict(choice))
    reference_rectify(jpegs[0], cam, out_hw, balance)
    t0 = time.process_time()
    for j in jpegs:
        reference_rectify(j, cam, out_hw, balance)
    ref_ms = (time.process_time() - t0) * 1e3 / max(len(jpegs), 1)
    rows.append({"reduction": 0, "fixed_point": False, "ms_per_image": ref_ms,
                 "psnr_db": float("inf"), "default": False})  # fmt: skip
    return rows
