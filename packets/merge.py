"""Several LiDARs in one packet: their sweeps carried into the camera, each by its own pose.

A view that merges LiDARs takes, from each, the sweep nearest its stamp and that sweep's
camera-from-LiDAR transform through the odometry at both stamps (`packets.poses.lidar_to_camera`:
T_cam_lidar_i = T_cam_base · T_base_odom(tau) · T_odom_base(tau_P_i) · T_base_lidar_i): every
point lands in the camera frame (equivalently the base frame at the view's stamp) through its
own sweep's pose. Each point keeps its own sweep's delta tau; a cell's delta tau is the mean
over the points that support it (`cell_delta_tau`), so a cell seen by one LiDAR carries that
LiDAR's delta tau exactly and a cell seen by two their support-weighted mean.

Pure math: arrays in, arrays out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from packets._checks import require_finite, require_finite_scalar, require_shape
from packets.rigid import apply_T
from packets.statistics import cell_depth_stats
from packets.support import SupportSets
from schemas.errors import DataError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SweepPart:
    """One LiDAR's contribution to a view.

    xyz: (N, 3) points in the LiDAR frame at the sweep's stamp, metres.
    T_cam_lidar: (4, 4) camera-from-LiDAR through the sweep's own pose.
    delta_tau_s: the sweep's stamp minus the view's (s).
    features: (N, C_u) per-point features of the sweep, or None (no h).
    """

    xyz: npt.ArrayLike
    T_cam_lidar: npt.ArrayLike
    delta_tau_s: float
    features: npt.NDArray[Any] | torch.Tensor | None = None


@dataclass(frozen=True)
class MergedSweeps:
    """The parts' points in the camera frame, in part order.

    xyz_cam: (N, 3) float64 camera-frame metres (N = sum of the parts' points).
    delta_tau_s: (N,) float64 each point's own sweep's delta tau (s).
    features: (N, C_u) rows of the parts' features in the same order, or None.
    sizes: points of each part.
    """

    xyz_cam: F64
    delta_tau_s: F64
    features: npt.NDArray[Any] | torch.Tensor | None
    sizes: tuple[int, ...]


def merge_in_camera(parts: Sequence[SweepPart]) -> MergedSweeps:
    """Carry every part's points into the camera frame and concatenate them (float64).

    Features are concatenated when every part has them (all numpy or all torch, one width);
    none when no part has them; a DataError when only some do or widths differ.
    """
    if not parts:
        raise DataError("merging LiDARs needs at least one sweep")
    xyz, dtau, sizes = [], [], []
    for i, part in enumerate(parts):
        pts = np.asarray(part.xyz, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise DataError(f"sweep {i} of the merge: xyz must be (N, 3), got {pts.shape}")
        T = np.asarray(part.T_cam_lidar, dtype=np.float64)
        require_shape(f"T_cam_lidar of sweep {i}", T, (4, 4))
        require_finite(f"T_cam_lidar of sweep {i}", T)
        dt = require_finite_scalar(f"delta_tau_s of sweep {i}", part.delta_tau_s)
        xyz.append(apply_T(pts, T))
        dtau.append(np.full(pts.shape[0], dt))
        sizes.append(int(pts.shape[0]))
    return MergedSweeps(np.concatenate(xyz), np.concatenate(dtau),
                        _features(parts, sizes), tuple(sizes))


def _features(parts: Sequence[SweepPart],
              sizes: list[int]) -> npt.NDArray[Any] | torch.Tensor | None:
    """The parts' features stacked in part order (see `merge_in_camera`)."""
    feats = [p.features for p in parts]
    if all(f is None for f in feats):
        return None
    if any(f is None for f in feats):
        raise DataError("merging LiDARs: some sweeps have point features and some do not")
    widths = {int(f.shape[1]) for f in feats if f is not None}
    if len(widths) != 1:
        raise DataError(f"merging LiDARs: point features of widths {sorted(widths)}")
    for f, n in zip(feats, sizes, strict=True):
        if f is not None and int(f.shape[0]) != n:
            raise DataError(f"point features have {f.shape[0]} rows for a sweep of {n} points")
    if all(isinstance(f, torch.Tensor) for f in feats):
        return torch.cat([f for f in feats if isinstance(f, torch.Tensor)])
    return np.concatenate([f.detach().numpy() if isinstance(f, torch.Tensor) else f
                           for f in feats if f is not None])


def cell_delta_tau(sup: SupportSets, point_delta_tau_s: npt.ArrayLike) -> F64:
    """(H*W,) float64 mean delta tau (s) of each cell's support points; 0 on empty cells.

    point_delta_tau_s: (N,) per point of the merged sweep (rows `sup.point_idx` are read).
    Exact where every support point of a cell shares one value (a shifted mean).
    """
    d = np.asarray(point_delta_tau_s, dtype=np.float64)
    require_shape("point delta tau", d, (sup.n_points,))
    require_finite("point delta tau", d)
    return cell_depth_stats(sup.cell, d[sup.point_idx], sup.n_cells).mean
