"""Pure pieces of the Rerun view: which views to show, colours, packet channels as images.

No I/O here: the reader (`pipeline.analysis.view.source`) and the writer
(`pipeline.analysis.view.writer`) call these on arrays. Stamps are int64 ns; depths and
distances metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from matplotlib import colormaps

from schemas.channels import DELTA_TAU, LOG1P_MEAN_DEPTH, VALIDITY, channel_index, n_g

U8 = npt.NDArray[np.uint8]
F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]

_TURBO: U8 = (colormaps["turbo"](np.linspace(0.0, 1.0, 256))[:, :3] * 255).round().astype(
    np.uint8)


@dataclass(frozen=True)
class ViewPlan:
    """The views a recording file will show, per camera, and what was left out.

    frames: camera -> sorted (k,) int64 frame numbers to show.
    in_range: views inside the time range (all cameras); skipped: of those, views left out by
    `max_views` (the latest ones); last_kept_ns: stamp of the latest shown view (None if none).
    """

    frames: dict[str, I64]
    in_range: int
    skipped: int
    last_kept_ns: int | None

    @property
    def shown(self) -> int:
        """Number of views shown."""
        return sum(int(f.size) for f in self.frames.values())


def plan_views(stamps: dict[str, I64], start_ns: int | None, end_ns: int | None,
               max_views: int | None) -> ViewPlan:
    """Views with start_ns <= stamp <= end_ns (None: open), at most the `max_views` earliest.

    stamps: camera -> (N,) int64 image stamps of frames 0..N-1 (any order). Ties in stamp keep
    the camera order of the mapping.
    """
    if max_views is not None and max_views < 0:
        raise ValueError(f"max_views must be >= 0, got {max_views}")
    cams = list(stamps)
    cam_of = np.concatenate([np.full(len(stamps[c]), i, np.int64) for i, c in enumerate(cams)]
                            or [np.zeros(0, np.int64)])
    frame = np.concatenate([np.arange(len(stamps[c]), dtype=np.int64) for c in cams]
                           or [np.zeros(0, np.int64)])
    t = np.concatenate([np.asarray(stamps[c], np.int64) for c in cams]
                       or [np.zeros(0, np.int64)])
    idx = np.flatnonzero(in_range(t, start_ns, end_ns))
    idx = idx[np.lexsort((cam_of[idx], t[idx]))]  # by stamp, then camera
    kept = idx if max_views is None else idx[:max_views]
    frames = {c: np.sort(frame[kept[cam_of[kept] == i]]) for i, c in enumerate(cams)}
    last = int(t[kept[-1]]) if kept.size else None
    return ViewPlan(frames, int(idx.size), int(idx.size - kept.size), last)


def in_range(stamps: npt.ArrayLike, start_ns: int | None, end_ns: int | None
             ) -> npt.NDArray[np.bool_]:
    """(N,) bool: start_ns <= stamps <= end_ns (int64 ns), either bound open when None."""
    t = np.asarray(stamps, np.int64)
    keep = np.ones(t.shape, bool)
    if start_ns is not None:
        keep &= t >= start_ns
    if end_ns is not None:
        keep &= t <= end_ns
    return keep


def depth_colors(depth: npt.ArrayLike, lo: float | None = None, hi: float | None = None) -> U8:
    """(N, 3) uint8 turbo colours of (N,) depths: near blue, far red; lo/hi default to the
    2nd and 98th percentiles (a constant depth maps to the middle colour)."""
    d = np.asarray(depth, dtype=np.float64)
    if d.size == 0:
        return np.zeros((0, 3), np.uint8)
    lo = float(np.percentile(d, 2)) if lo is None else lo
    hi = float(np.percentile(d, 98)) if hi is None else hi
    span = hi - lo
    s = np.full(d.shape, 0.5) if span <= 0 else np.clip((d - lo) / span, 0.0, 1.0)
    out: U8 = _TURBO[np.round(s * 255).astype(np.int64)]
    return out


def packet_channels(g: npt.ArrayLike) -> dict[str, npt.NDArray[Any]]:
    """The packet grid of one view as images, from g (n_g, H, W) float32 (the channels of
    schemas.channels, eq. 9).

    validity: (H, W) uint8, 255 on cells with LiDAR support, else 0; mean_depth_m: (H, W)
    float32 mean depth (expm1 of channel 1), 0 on empty cells; dtau_s: (H, W) float32 signed
    sweep-minus-image time in seconds, 0 on empty cells.
    """
    arr = np.asarray(g, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[0] != n_g():
        raise ValueError(f"g must be ({n_g()}, H, W), got {arr.shape}")
    occupied = arr[channel_index(VALIDITY)] > 0
    log_depth = arr[channel_index(LOG1P_MEAN_DEPTH)].astype(np.float64)
    depth = np.where(occupied, np.expm1(log_depth), 0.0).astype(np.float32)
    return {"validity": (occupied * 255).astype(np.uint8), "mean_depth_m": depth,
            "dtau_s": np.where(occupied, arr[channel_index(DELTA_TAU)], 0.0).astype(np.float32)}


def subsample(n: int, max_points: int | None) -> I64:
    """Indices of at most `max_points` of n points, evenly strided (all when None or n fits)."""
    if max_points is None or n <= max_points:
        return np.arange(n, dtype=np.int64)
    if max_points <= 0:
        return np.zeros(0, np.int64)
    out: I64 = np.floor(np.arange(max_points) * (n / max_points)).astype(np.int64)
    return out


def T_world_lidar(T_world_cam: npt.ArrayLike, T_cam_lidar: npt.ArrayLike) -> npt.NDArray[
        np.float64]:
    """(4, 4) pose of the LiDAR at the sweep stamp in the odometry (world) frame.

    With T_world_cam = T_odom_base(tau) T_base_cam and the odometry chain T_cam_lidar =
    T_cam_base T_base_odom(tau) T_odom_base(tau_P) T_base_lidar, the product is
    T_odom_base(tau_P) T_base_lidar: the sweep placed by the odometry at its own stamp.
    """
    out: npt.NDArray[np.float64] = (np.asarray(T_world_cam, np.float64)
                                    @ np.asarray(T_cam_lidar, np.float64))
    return out
