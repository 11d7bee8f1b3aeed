"""Camera models from CameraInfo and the one-remap rectifier: fisheye JPEG -> pinhole output.

The output camera is a pinhole with intrinsics `K_out` for an image of (out_h, out_w) pixels:
the equidistant image is undistorted to the pinhole `K_rect` that OpenCV's
`estimateNewCameraMatrixForUndistortRectify` gives at the raw size (with `balance`), centre-cropped
to the output aspect and resized. Crop and resize are folded into `K_out` (pixel centres at
integer coordinates), so the whole chain is one `cv2.remap` from the decoded JPEG straight to
the output size, with the map built once per camera. When the output is at least 2, 4 or 8 times
smaller than the raw image, the JPEG is decoded at that reduced scale and the map scaled to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import simplejpeg

from pipeline.ingest.errors import CalibrationMismatchError, CorruptImageError
from pipeline.ingest.sources.image_decode import ImageKind, png_to_rgb, raw_to_rgb, reduce_to
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]

EQUIDISTANT_NAMES = ("equidistant", "fisheye", "kannala_brandt", "kb4")
PINHOLE_NAMES = ("plumb_bob", "rational_polynomial", "pinhole", "")
REDUCE_FLAGS = {
    1: cv2.IMREAD_COLOR,
    2: cv2.IMREAD_REDUCED_COLOR_2,
    4: cv2.IMREAD_REDUCED_COLOR_4,
    8: cv2.IMREAD_REDUCED_COLOR_8,
}


@dataclass(frozen=True)
class RawCamera:
    """A raw camera: size in pixels, model ('equidistant' or 'pinhole'), K (3, 3), D (n,)."""

    camera: str
    frame_id: str
    width: int
    height: int
    model: str
    K: F64
    D: F64


def _field(msg: Any, upper: str) -> Any:
    """A CameraInfo field by its ROS1 (upper) or ROS2 (lower) name."""
    return getattr(msg, upper) if hasattr(msg, upper) else getattr(msg, upper.lower())


def camera_from_info(camera: str, msg: Any, where: str) -> RawCamera:
    """RawCamera from a sensor_msgs/CameraInfo; ValueError naming `where` if unusable."""
    name = str(msg.distortion_model).lower()
    if name in EQUIDISTANT_NAMES:
        model = "equidistant"
    elif name in PINHOLE_NAMES:
        model = "pinhole"
    else:
        raise DataError(f"{where}: unsupported distortion model {msg.distortion_model!r}")
    K = np.asarray(_field(msg, "K"), dtype=np.float64).reshape(3, 3)
    D = np.asarray(_field(msg, "D"), dtype=np.float64).ravel()
    width, height = int(msg.width), int(msg.height)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or width <= 0 or height <= 0 or not np.isfinite(K).all():
        raise DataError(f"{where}: bad camera_info K={K.tolist()} size={width}x{height}")
    if model == "equidistant" and D.size != 4:
        raise DataError(f"{where}: equidistant model needs 4 coefficients, got {D.size}")
    return RawCamera(camera, str(msg.header.frame_id).lstrip("/"), width, height, model, K, D)


def rectified_K(cam: RawCamera, balance: float) -> F64:
    """(3, 3) pinhole K at the raw size after undistortion (OpenCV's choice with `balance`)."""
    size = (cam.width, cam.height)
    if cam.model == "equidistant":
        K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
            cam.K, cam.D.reshape(1, 4), size, np.eye(3), balance=balance
        )
    else:
        K_new, _ = cv2.getOptimalNewCameraMatrix(cam.K, cam.D, size, 1.0 - balance, size)
    return np.asarray(K_new, dtype=np.float64)


def crop_resize_K(K: F64, in_hw: tuple[int, int], out_hw: tuple[int, int]) -> F64:
    """K after a centre crop of an (H, W) image to the aspect of `out_hw` and a resize to it."""
    (h, w), (oh, ow) = in_hw, out_hw
    crop_w, crop_h = (h * ow / oh, h) if w * oh > ow * h else (w, w * oh / ow)
    x0, y0 = (w - crop_w) / 2.0, (h - crop_h) / 2.0
    s = ow / crop_w
    out = np.array(K, dtype=np.float64)
    out[0, 0], out[1, 1] = K[0, 0] * s, K[1, 1] * s
    out[0, 2] = s * (K[0, 2] - x0 + 0.5) - 0.5
    out[1, 2] = s * (K[1, 2] - y0 + 0.5) - 0.5
    return out


def output_K(cam: RawCamera, out_hw: tuple[int, int], balance: float) -> F64:
    """(3, 3) intrinsics of the rectified, cropped and resized output image."""
    return crop_resize_K(rectified_K(cam, balance), (cam.height, cam.width), out_hw)


def choose_reduction(cam: RawCamera, K_out: F64, allow: bool) -> int:
    """Largest JPEG decode reduction r in {1, 2, 4, 8} that does not upsample the centre."""
    if not allow:
        return 1
    ratio = min(cam.K[0, 0] / K_out[0, 0], cam.K[1, 1] / K_out[1, 1])
    return max((r for r in REDUCE_FLAGS if r <= ratio + 1e-9), default=1)


def raw_map(cam: RawCamera, K_out: F64, out_hw: tuple[int, int]) -> tuple[F32, F32]:
    """Float maps (out_h, out_w) giving, per output pixel, the raw full-size pixel to sample."""
    size = (out_hw[1], out_hw[0])
    if cam.model == "equidistant":
        mx, my = cv2.fisheye.initUndistortRectifyMap(
            cam.K, cam.D.reshape(1, 4), np.eye(3), K_out, size, cv2.CV_32FC1
        )
    else:
        mx, my = cv2.initUndistortRectifyMap(cam.K, cam.D, np.eye(3), K_out, size, cv2.CV_32FC1)
    return np.asarray(mx, dtype=np.float32), np.asarray(my, dtype=np.float32)


@dataclass(frozen=True)
class Rectifier:
    """One camera's decode + remap: reduction r, fixed-point maps into the reduced image."""

    cam: RawCamera
    K_out: F64
    out_hw: tuple[int, int]
    reduction: int
    map1: Any
    map2: Any

    def decode(self, data: bytes | U8, where: str) -> U8:
        """Decode a JPEG at the chosen reduction, RGB; CorruptImageError naming `where`."""
        buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes) else data
        check_jpeg(buf, where)
        r = self.reduction
        want = (-(-self.cam.height // r), -(-self.cam.width // r))
        img = strict_decode(buf, want, r, where)
        if img.shape[:2] != want:
            got = f"{img.shape[1]}x{img.shape[0]}"
            raise CorruptImageError(
                f"{where}: JPEG decodes (at 1/{r}) to {got}, expected {want[1]}x{want[0]} "
                f"for the CameraInfo size {self.cam.width}x{self.cam.height}"
            )
        return np.asarray(img, dtype=np.uint8)

    def decode_message(self, kind: ImageKind, msg: Any, where: str) -> U8:
        """RGB at the decode reduction of an Image (`raw`) or CompressedImage (`jpeg`, `png`);
        CorruptImageError for damaged data, CalibrationMismatchError for an uncompressed or PNG
        image whose size is not its CameraInfo's."""
        data = np.asarray(msg.data, dtype=np.uint8)
        if kind == "jpeg":
            return self.decode(data, where)
        img = raw_to_rgb(msg, where) if kind == "raw" else png_to_rgb(data, where)
        if img.shape[:2] != (self.cam.height, self.cam.width):
            raise CalibrationMismatchError(
                f"{where}: image is {img.shape[1]}x{img.shape[0]}, its CameraInfo says "
                f"{self.cam.width}x{self.cam.height}")  # fmt: skip
        r = self.reduction
        return reduce_to(img, (-(-self.cam.height // r), -(-self.cam.width // r)))

    def apply(self, data: bytes | U8, where: str) -> U8:
        """(out_h, out_w, 3) uint8 RGB rectified output from JPEG bytes."""
        return self.remap(self.decode(data, where))

    def remap(self, decoded: U8) -> U8:
        """(out_h, out_w, 3) uint8 RGB rectified output from a `decode`d image."""
        out = cv2.remap(decoded, self.map1, self.map2, cv2.INTER_LINEAR)
        return np.asarray(out, dtype=np.uint8)


def strict_decode(buf: U8, hw: tuple[int, int], reduction: int, where: str) -> U8:
    """RGB decode at 1/`reduction` (at least `hw`) that refuses damaged entropy-coded data.

    libjpeg-turbo (through simplejpeg) with warnings as errors: "Corrupt JPEG data", premature
    end of data and the like raise instead of decoding grey or smeared blocks, as OpenCV's
    imdecode does silently. Same scaled IDCT and upsampling as OpenCV's reduced decode, so the
    pixels are the same. CorruptImageError naming `where` for any libjpeg error or warning.
    """
    try:
        img = simplejpeg.decode_jpeg(buf, "RGB", min_height=hw[0], min_width=hw[1],
                                     min_factor=reduction)  # fmt: skip
    except ValueError as err:  # a libjpeg error or (strict) warning
        raise CorruptImageError(f"{where}: JPEG data corrupt (libjpeg: {err})") from err
    return np.asarray(img, dtype=np.uint8)


def check_jpeg(buf: U8, where: str) -> None:
    """Refuse data that is not a whole, well-formed JPEG (CorruptImageError naming `where`).

    Checks the start and end markers, then the first scan's entropy-coded data: there a 0xFF
    byte may only be followed by 0x00 (stuffing), a restart marker or more 0xFF fill, up to
    the next real marker, which must be the end of the image (baseline) or a marker that
    may follow a scan (progressive). libjpeg decodes damaged data silently (grey or smeared
    blocks), so random corruption inside a JPEG is caught here instead. Not caught: a JPEG
    cut at an MCU boundary and given a new end marker (it decodes grey to the bottom).
    """
    if buf.size == 0:
        raise CorruptImageError(f"{where}: empty image payload (0 bytes)")
    if buf.size < 4 or buf[0] != 0xFF or buf[1] != 0xD8:
        raise CorruptImageError(f"{where}: not a JPEG (no start-of-image marker)")
    tail = buf[-64:]
    ends = np.flatnonzero((tail[:-1] == 0xFF) & (tail[1:] == 0xD9))
    if ends.size == 0 or not bool((tail[ends[-1] + 2 :] == 0).all()):
        raise CorruptImageError(f"{where}: JPEG is cut short (no end-of-image marker)")
    eoi = buf.size - tail.size + int(ends[-1])
    start, progressive = _scan_start(buf, where)
    _check_scans(buf, start, eoi, _AFTER_SCAN if progressive else _AFTER_SEQUENTIAL_SCAN, where)


def _check_scans(buf: U8, start: int, eoi: int, allowed: frozenset[int], where: str) -> None:
    """Walk the markers between the first scan data (`start`) and the end of image (`eoi`)."""
    seg = buf[start : eoi + 2]
    ff = np.flatnonzero(seg[:-1] == 0xFF)
    nxt = seg[ff + 1]
    stuffing = (nxt == 0x00) | (nxt == 0xFF) | ((nxt >= 0xD0) & (nxt <= 0xD7))
    marks = ff[~stuffing] + start  # byte offsets of real markers, ascending
    pos = start
    while True:
        i = int(np.searchsorted(marks, pos))
        first = int(marks[i]) if i < marks.size else eoi
        code = int(buf[first + 1])
        if code == 0xD9 and first == eoi:
            return
        if code not in allowed or code == 0xD9 or first + 4 > eoi:
            break
        pos = first + 2 + (int(buf[first + 2]) << 8 | int(buf[first + 3]))  # skip its segment
        if pos > eoi or not _segment_ok(buf[first + 4 : pos], code):
            break
    raise CorruptImageError(
        f"{where}: JPEG data corrupt: marker 0xFF{code:02X} at byte {first} inside the "
        f"image data (end of image at byte {eoi})"
    )


_AFTER_SCAN = frozenset({0xD9, 0xC4, 0xCC, 0xDA, 0xDB, 0xDD, 0xFE, *range(0xE0, 0xF0)})
"""Markers that may end a scan of a progressive JPEG: EOI, tables, the next scan."""
_AFTER_SEQUENTIAL_SCAN = frozenset({0xD9, 0xC4, 0xDA, 0xDB, 0xDD})
"""Markers that may end a scan of a sequential JPEG (EOI; tables of a next, rare, scan)."""
_PROGRESSIVE_SOF = frozenset({0xC2, 0xC6, 0xCA, 0xCE})


def _segment_ok(body: U8, code: int) -> bool:
    """Whether a table or scan header between scans is self-consistent (body: after length).

    Random bytes that happen to form such a marker almost never pass: a Huffman table's
    code counts must add up to its length, a quantization table has 64 entries, a
    restart interval 2 bytes, a scan header 1-4 components.
    """
    n = body.size
    if code == 0xDD:  # DRI
        return n == 2
    if code == 0xDA:  # SOS
        return n >= 4 and 1 <= int(body[0]) <= 4 and n == 4 + 2 * int(body[0])
    if code == 0xDB:  # DQT: (Pq/Tq, 64 entries of 1 or 2 bytes) repeated
        pos = 0
        while pos < n:
            pq, tq = int(body[pos]) >> 4, int(body[pos]) & 15
            if pq > 1 or tq > 3:
                return False
            pos += 1 + 64 * (pq + 1)
        return pos == n
    if code == 0xC4:  # DHT: (Tc/Th, 16 counts, symbols) repeated
        pos = 0
        while pos < n:
            tc, th = int(body[pos]) >> 4, int(body[pos]) & 15
            if tc > 1 or th > 3 or pos + 17 > n:
                return False
            pos += 17 + int(body[pos + 1 : pos + 17].sum())
        return pos == n
    return True  # APPn, COM, DAC: free-form


def _scan_start(buf: U8, where: str) -> tuple[int, bool]:
    """(byte offset of the first scan's entropy-coded data, progressive frame?)."""
    pos, progressive = 2, False
    while pos + 4 <= buf.size:
        if buf[pos] != 0xFF:
            raise CorruptImageError(f"{where}: JPEG header corrupt at byte {pos}")
        code = int(buf[pos + 1])
        if code == 0xFF:  # fill byte before a marker
            pos += 1
            continue
        length = int(buf[pos + 2]) << 8 | int(buf[pos + 3])
        if length < 2:
            raise CorruptImageError(f"{where}: JPEG header corrupt at byte {pos}")
        pos += 2 + length
        progressive |= code in _PROGRESSIVE_SOF
        if code == 0xDA:
            return pos, progressive
    raise CorruptImageError(f"{where}: JPEG has no image data (no start-of-scan marker)")


def build_rectifier(
    cam: RawCamera,
    out_hw: tuple[int, int],
    balance: float = 0.0,
    reduced: bool = True,
    reduction: int | None = None,
    fixed_point: bool = True,
) -> Rectifier:
    """The rectifier of one camera; `reduction` forces a decode scale (else chosen)."""
    K_out = output_K(cam, out_hw, balance)
    r = reduction if reduction is not None else choose_reduction(cam, K_out, reduced)
    fx, fy = raw_map(cam, K_out, out_hw)
    mx = ((fx + 0.5) / r - 0.5).astype(np.float32)  # full-size -> reduced pixel centres
    my = ((fy + 0.5) / r - 0.5).astype(np.float32)
    m1, m2 = cv2.convertMaps(mx, my, cv2.CV_16SC2) if fixed_point else (mx, my)
    return Rectifier(cam, K_out, out_hw, r, m1, m2)


def rectify_nearest(raw: npt.NDArray[Any], rect: Rectifier) -> npt.NDArray[Any]:
    """Resample a full-size raw-camera array (H, W[, C]) into the output view, nearest neighbour.

    For quantities that must not be blended (depth maps, labels): output pixel (u, v) takes the
    raw pixel nearest to where the rectifier samples; outside the raw image gives 0.
    """
    mx, my = raw_map(rect.cam, rect.K_out, rect.out_hw)
    out = cv2.remap(raw, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return np.asarray(out)
