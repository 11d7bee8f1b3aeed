"""Fisheye camera rendering: one raycast per image, texture shading, true depth, JPEG bytes."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from pipeline.synth.rig import FisheyeCamera
from pipeline.synth.scene import Raycaster
from pipeline.synth.texture import rotate_soa, shade, to_bgr8
from schemas.errors import DataError

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]


@dataclass(frozen=True)
class Frame:
    """A rendered image: BGR (H, W, 3) uint8 and depth (H, W) float32 in metres along the optical
    z axis (0 where the ray hits nothing)."""

    bgr: U8
    depth: F32


class CameraRenderer:
    """Renders one camera; the per-pixel rays are computed once."""

    def __init__(self, camera: FisheyeCamera, raycaster: Raycaster) -> None:
        """Precompute the unit pixel rays (3, H*W) in the optical frame."""
        self.camera = camera
        self._rays = np.ascontiguousarray(camera.pixel_rays().reshape(-1, 3).T)
        self._rc = raycaster

    def render(self, T_odom_cam: F64) -> Frame:
        """Image and depth seen from the optical-frame pose T_odom_cam (4, 4)."""
        cam = self.camera
        dirs = rotate_soa(T_odom_cam[:3, :3], self._rays)  # (3, N) world
        o = T_odom_cam[:3, 3].astype(np.float32)
        hits = self._rc.cast_soa(o, dirs)
        hit = hits.material >= 0
        t = np.where(hit, hits.t, np.float32(0.0))
        p = dirs * t
        p += o[:, None]
        rgb = shade(p, hits.normal, hits.material, dirs[2])
        depth = t * self._rays[2]
        shape = (cam.height, cam.width)
        return Frame(to_bgr8(rgb, *shape), depth.reshape(shape))


def encode_jpeg(bgr: U8, quality: int) -> U8:
    """JPEG bytes (n,) uint8 of a BGR image via cv2.imencode."""
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise DataError(f"cv2.imencode failed for an image of shape {bgr.shape}")
    return np.asarray(buf, dtype=np.uint8).ravel()
