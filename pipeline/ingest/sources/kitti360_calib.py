"""Pure parsers of the KITTI-360 raw layout's files: strings or bytes in, arrays out.

Formats (read from the public `autonomousvision/kitti360Scripts` helpers
`devkits/commons/loadCalibration.py` and `helpers/project.py`, not from magnitudes):

- `timestamps.txt`: one `YYYY-MM-DD HH:MM:SS.fffffffff` per line, line i = frame i of that sensor
  folder. Read as UTC (the release names no zone; the stamps are only ever differenced) ->
  int64 ns since the epoch, digit by digit, never through a float.
- `calibration/perspective.txt`: `KEY: v v v ...` lines; per perspective camera NN in {00, 01}
  `P_rect_NN` (3x4, row-major), `R_rect_NN` (3x3: unrectified camera -> rectified camera) and
  `S_rect_NN` (width height of the rectified image, pixels).
- `calibration/calib_cam_to_velo.txt`: 12 numbers, the 3x4 rigid map of (unrectified) camera 0
  coordinates into Velodyne coordinates: T_velo_cam0.
- `calibration/calib_cam_to_pose.txt`: `image_NN: ` + 12 numbers per camera, T_pose_camNN (the
  `pose` frame is the IMU/GPS frame poses.txt is given in).
- `data_poses/<seq>/poses.txt`: `frame` + 12 numbers (3x4 T_world_pose); `cam0_to_world.txt`:
  `frame` + 16 numbers (4x4 T_world_rectcam0). Rows exist only for some frames (KITTI-360 drops
  frames where the vehicle stands still); `frame` indexes `image_00`'s frames.
- `velodyne_points/data/NNNNNNNNNN.bin`: float32 little-endian x, y, z, reflectance per point (m).

Every error is a DataError naming the file (the `where` argument) and the line.
"""

from __future__ import annotations

import calendar
import re
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from packets.poses import F64
from schemas.errors import DataError

I64 = npt.NDArray[np.int64]
F32 = npt.NDArray[np.float32]
VELO_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("reflectance", "<f4")])
"""One Velodyne point as stored in a `.bin` sweep (16 bytes)."""
_STAMP = re.compile(r"^(\d{4})-(\d{2})-(\d{2}) (\d{2}):(\d{2}):(\d{2})(?:\.(\d{1,9}))?$")
NS = 1_000_000_000


@dataclass(frozen=True)
class PerspectiveCamera:
    """One rectified perspective camera of perspective.txt.

    P_rect (3, 4) projection of rectified-camera points to pixels (its left 3x3 is K);
    R_rect (3, 3) unrectified camera -> rectified camera; width, height of `data_rect` images.
    """

    name: str
    P_rect: F64
    R_rect: F64
    width: int
    height: int

    @property
    def K(self) -> F64:
        """(3, 3) intrinsics of the rectified image (pixels)."""
        return np.asarray(self.P_rect[:, :3], dtype=np.float64)


def parse_stamp(text: str, where: str) -> int:
    """One `YYYY-MM-DD HH:MM:SS.fffffffff` (UTC) -> int64 ns since the epoch."""
    m = _STAMP.match(text.strip())
    if m is None:
        raise DataError(f"{where}: {text.strip()!r} is not a YYYY-MM-DD HH:MM:SS.fffffffff stamp")
    y, mo, d, h, mi, s = (int(g) for g in m.groups()[:6])
    if not (1 <= mo <= 12 and 1 <= d <= 31 and h < 24 and mi < 60 and s < 61):
        raise DataError(f"{where}: {text.strip()!r} is not a valid date and time")
    frac = (m.group(7) or "").ljust(9, "0")
    return calendar.timegm((y, mo, d, h, mi, s, 0, 0, 0)) * NS + int(frac or "0")


def parse_timestamps(text: str, where: str) -> I64:
    """A timestamps.txt -> (N,) int64 ns, line i = frame i; blank trailing lines are ignored."""
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    return np.array([parse_stamp(line, f"{where} line {i + 1}") for i, line in enumerate(lines)],
                    dtype=np.int64).reshape(-1)  # fmt: skip


def _numbers(values: list[str], n: int, where: str) -> F64:
    """Exactly `n` finite floats from text fields."""
    try:
        out = np.array([float(v) for v in values], dtype=np.float64)
    except ValueError as err:
        raise DataError(f"{where}: not a number ({err})") from err
    if out.size != n:
        raise DataError(f"{where}: {out.size} numbers, expected {n}")
    if not np.isfinite(out).all():
        raise DataError(f"{where}: non-finite value in {out.tolist()}")
    return out


def parse_keyed(text: str, where: str) -> dict[str, tuple[int, list[str]]]:
    """`KEY: fields...` lines -> {KEY: (line number, fields)}; lines without a colon are skipped."""
    out: dict[str, tuple[int, list[str]]] = {}
    for i, line in enumerate(text.splitlines()):
        key, sep, rest = line.partition(":")
        if sep and key.strip():
            out[key.strip()] = (i + 1, rest.split())
    return out


def _keyed_matrix(keys: dict[str, tuple[int, list[str]]], key: str, shape: tuple[int, int],
                  where: str) -> F64:  # fmt: skip
    """The matrix of one `KEY:` line, reshaped; DataError when absent or malformed."""
    if key not in keys:
        raise DataError(f"{where}: no {key} line (keys: {', '.join(sorted(keys)) or 'none'})")
    line, fields = keys[key]
    return _numbers(fields, shape[0] * shape[1], f"{where} line {line} ({key})").reshape(shape)


def rigid(T34: F64, where: str) -> F64:
    """(4, 4) from a (3, 4) rigid transform; DataError when its rotation is not orthonormal."""
    T = np.eye(4)
    T[:3, :] = T34
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-5 or abs(np.linalg.det(R) - 1.0) > 1e-5:
        raise DataError(f"{where}: the rotation is not orthonormal: {R.tolist()}")
    return T


def parse_perspective(text: str, where: str, cameras: tuple[str, ...] = ("00", "01")
                      ) -> dict[str, PerspectiveCamera]:  # fmt: skip
    """perspective.txt -> {`image_NN`: PerspectiveCamera} for the cameras it holds (P_rect_NN).

    A camera with P_rect_NN but without R_rect_NN or S_rect_NN is an error naming the key.
    """
    keys = parse_keyed(text, where)
    out = {}
    for nn in cameras:
        if f"P_rect_{nn}" not in keys:
            continue
        P = _keyed_matrix(keys, f"P_rect_{nn}", (3, 4), where)
        R = _keyed_matrix(keys, f"R_rect_{nn}", (3, 3), where)
        size = _keyed_matrix(keys, f"S_rect_{nn}", (1, 2), where)[0]
        w, h = round(float(size[0])), round(float(size[1]))
        if P[0, 0] <= 0 or P[1, 1] <= 0 or w <= 0 or h <= 0:
            raise DataError(f"{where}: camera {nn}: bad P_rect_{nn} {P.tolist()} or size {w}x{h}")
        rigid(np.hstack([R, np.zeros((3, 1))]), f"{where} R_rect_{nn}")
        out[f"image_{nn}"] = PerspectiveCamera(f"image_{nn}", P, R, w, h)
    if not out:
        raise DataError(f"{where}: no P_rect_NN line for cameras {', '.join(cameras)}")
    return out


def parse_rigid_file(text: str, where: str) -> F64:
    """calib_cam_to_velo.txt (12 numbers, a 3x4) -> (4, 4) T_velo_cam0."""
    return rigid(_numbers(text.split(), 12, where).reshape(3, 4), where)


def parse_cam_to_pose(text: str, where: str) -> dict[str, F64]:
    """calib_cam_to_pose.txt -> {`image_NN`: (4, 4) T_pose_camNN} for every `image_NN:` line."""
    keys = parse_keyed(text, where)
    out = {key: rigid(_keyed_matrix(keys, key, (3, 4), where), f"{where} ({key})")
           for key in keys if re.fullmatch(r"image_\d\d", key)}  # fmt: skip
    if not out:
        raise DataError(f"{where}: no image_NN line")
    return out


def parse_poses(text: str, where: str, width: int = 12) -> tuple[I64, npt.NDArray[np.float64]]:
    """poses.txt (`width` 12: frame + 3x4) or cam0_to_world.txt (16: frame + 4x4) ->
    frames (N,) int64 strictly increasing, T (N, 4, 4) float64."""
    frames: list[int] = []
    Ts: list[F64] = []
    for i, line in enumerate(text.splitlines()):
        fields = line.split()
        if not fields:
            continue
        here = f"{where} line {i + 1}"
        try:
            frame = int(float(fields[0]))
        except ValueError as err:
            raise DataError(f"{here}: frame index {fields[0]!r} is not a number") from err
        vals = _numbers(fields[1:], width, here).reshape(-1, 4)
        Ts.append(rigid(vals[:3], here))
        if width == 16 and np.abs(vals[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise DataError(f"{here}: last row {vals[3].tolist()} is not 0 0 0 1")
        if frames and frame <= frames[-1]:
            raise DataError(f"{here}: frame {frame} does not follow frame {frames[-1]}")
        frames.append(frame)
    return np.array(frames, dtype=np.int64), np.array(Ts, dtype=np.float64).reshape(-1, 4, 4)


def parse_velodyne(data: bytes, where: str) -> tuple[F32, F32]:
    """A `.bin` sweep -> xyz (N, 3) float32 m, reflectance (N,) float32."""
    if len(data) % VELO_DTYPE.itemsize:
        raise DataError(f"{where}: {len(data)} bytes is not a whole number of 16-byte points "
                        "(float32 x, y, z, reflectance)")  # fmt: skip
    pts = np.frombuffer(data, dtype=VELO_DTYPE)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float32)
    return xyz, np.asarray(pts["reflectance"], dtype=np.float32)
