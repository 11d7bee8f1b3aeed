"""Packet assembly l = [g; h] (eqs. 8-10) and the paper's LiDAR input ablation modes.

Modes: 'full' (g and h), 'geom_only' (g; h is never computed nor read: None), 'zero' (all-zero
g and h of the right shape), 'no_lidar' and 'learnable' (no packet tensors: g and h None; the
model supplies the learnable packet itself). In every mode the
support counts and drop statistics are real, so stats tables stay informative.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from packets._checks import require_finite, require_finite_scalar
from packets.merge import cell_delta_tau
from packets.pooling import DEFAULT_METHOD, PoolMethod, pool_support
from packets.projection import MIN_DEPTH_M, CameraModel, project_points
from packets.statistics import cell_depth_stats, explicit_channels
from packets.support import PATCH_PX, SupportSets, front_surface, support_sets
from schemas.channels import n_g
from schemas.errors import DataError
from schemas.modes import MODE_SPECS, PACKET_MODES, PacketMode, PacketModeSpec

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]
MODES: tuple[str, ...] = PACKET_MODES


@dataclass(frozen=True)
class SweepFeatures:
    """Per-point features (N, C_u) of one sweep, checked finite once and shared by its views."""

    values: npt.NDArray[Any] | torch.Tensor

    @classmethod
    def from_array(cls, values: npt.NDArray[Any] | torch.Tensor) -> SweepFeatures:
        """Validate shape (N, C_u), floating dtype and finiteness (ValueError names the row)."""
        if values.ndim != 2:
            raise DataError(f"point features must be (N, C_u), got shape {tuple(values.shape)}")
        arr = values.detach().float().numpy() if isinstance(values, torch.Tensor) else values
        if not np.issubdtype(arr.dtype, np.floating):
            raise DataError(f"point features must be floating point, got {arr.dtype}")
        require_finite("point features", arr)
        return cls(values)

    @property
    def shape(self) -> tuple[int, int]:
        """(N, C_u)."""
        return int(self.values.shape[0]), int(self.values.shape[1])


@dataclass(frozen=True)
class PacketStats:
    """Point accounting of one view: sweep size, drops, in-frustum points, occupied cells."""

    n_points: int
    n_behind: int
    n_too_near: int
    n_outside: int
    n_in_frustum: int
    n_front_dropped: int
    n_occupied_cells: int


@dataclass(frozen=True)
class Packet:
    """One view's LiDAR packet on the (H, W) latent grid.

    g: (n_g, H, W) float32 explicit channels (eq. 9, schemas.channels) or None ('no_lidar',
       'learnable').
    h: (C_u, H, W) float32 (float64 for float64 features) pooled descriptors, or None
       ('geom_only', 'no_lidar').
    counts: (H, W) int64 support size n_q of the support actually pooled.
    """

    mode: str
    g: F32 | None
    h: npt.NDArray[Any] | None
    counts: I64
    stats: PacketStats

    def tensor(self, c_u: int) -> F32:
        """(n_g + C_u, H, W) float32 [g; h], zeros where a component is absent ('geom_only')."""
        if not _spec(self.mode).has_tensor:
            raise DataError(f"a {self.mode!r} packet has no tensor (no data reaches the model)")
        h_, w_ = self.counts.shape
        n_explicit = n_g()
        out = np.zeros((n_explicit + c_u, h_, w_), dtype=np.float32)
        if self.g is not None:
            out[:n_explicit] = self.g
        if self.h is not None:
            if self.h.shape[0] != c_u:
                raise DataError(f"packet h has {self.h.shape[0]} channels, expected C_u={c_u}")
            out[n_explicit:] = self.h
        return out


def view_support(
    xyz: npt.ArrayLike,
    K: npt.ArrayLike,
    T_cam_lidar: npt.ArrayLike,
    hw: tuple[int, int],
    *,
    model: CameraModel = "pinhole",
    D: npt.ArrayLike | None = None,
    min_depth_m: float = MIN_DEPTH_M,
    patch: int = PATCH_PX,
) -> SupportSets:
    """Project a sweep (N, 3) metres into one view (image hw pixels) and build its support sets."""
    proj = project_points(xyz, K, T_cam_lidar, hw, model=model, D=D, min_depth_m=min_depth_m)
    return support_sets(proj, hw, min_depth_m, patch)


def _features(
    feat: SweepFeatures | npt.NDArray[Any] | torch.Tensor | None, n_points: int
) -> SweepFeatures:
    if feat is None:
        raise DataError("mode 'full' needs the sweep's point features")
    sf = feat if isinstance(feat, SweepFeatures) else SweepFeatures.from_array(feat)
    if sf.shape[0] != n_points:
        raise DataError(f"point features have {sf.shape[0]} rows for a sweep of {n_points} points")
    return sf


def packet_from_support(
    sup: SupportSets,
    delta_tau_s: float | npt.ArrayLike,
    feat: SweepFeatures | npt.NDArray[Any] | torch.Tensor | None,
    *,
    mode: PacketMode = "full",
    front_margin_m: float | None = None,
    c_u: int | None = None,
    method: PoolMethod = DEFAULT_METHOD,
    front_margin_rel: float = 0.0,
) -> Packet:
    """Assemble one view's packet from its support sets; delta_tau_s = tau_P - tau in seconds:
    one value for the view, or (N,) one per point of the sweep(s) the support indexes (merged
    LiDARs: each cell takes the mean over its pooled points, `packets.merge.cell_delta_tau`).

    front_margin_m: if set, both g and h use only points within this many metres behind each
    cell's nearest point, plus `front_margin_rel` times that point's depth (see
    `support.front_margins`). c_u: channel count for 'zero' when no features are given.
    """
    spec = _spec(mode)
    per_point = np.ndim(delta_tau_s) > 0
    dt: float | npt.NDArray[np.float64] = 0.0
    if not per_point:
        dt = require_finite_scalar("delta_tau_s", float(np.asarray(delta_tau_s)))
    sf = _features(feat, sup.n_points) if spec.reads_h else None
    if front_margin_m is not None:
        sup = front_surface(sup, front_margin_m, front_margin_rel)
    if per_point:  # over the support actually pooled
        dt = cell_delta_tau(sup, delta_tau_s)
    stats = cell_depth_stats(sup.cell, sup.depth, sup.n_cells)
    counts = stats.n.reshape(sup.grid_hw)
    pstats = PacketStats(
        n_points=sup.n_points,
        n_behind=sup.n_behind,
        n_too_near=sup.n_too_near,
        n_outside=sup.n_outside,
        n_in_frustum=int(sup.point_idx.size) + sup.n_front_dropped,
        n_front_dropped=sup.n_front_dropped,
        n_occupied_cells=int(np.count_nonzero(stats.n)),
    )
    if not spec.has_tensor:  # learnable: the model's own tensor, no data
        return Packet(mode, None, None, counts, pstats)
    if spec.feed == "zeros":
        width = c_u if c_u is not None else (None if feat is None else int(feat.shape[1]))
        if width is None:
            raise DataError("mode 'zero' needs c_u or the features to size h")
        zeros_g = np.zeros((n_g(), *sup.grid_hw), dtype=np.float32)
        zeros_h = np.zeros((width, *sup.grid_hw), dtype=np.float32)
        return Packet(mode, zeros_g, zeros_h, counts, pstats)
    g = explicit_channels(stats, dt, sup.grid_hw)
    if sf is None:
        return Packet(mode, g, None, counts, pstats)
    vals = sf.values
    if isinstance(vals, torch.Tensor):
        h_np: npt.NDArray[Any] = pool_support(vals.detach(), sup, method).numpy()
    else:
        h_np = pool_support(vals, sup, method)
    require_finite("pooled descriptors h", h_np)  # float32 sums can still overflow
    return Packet(mode, g, h_np, counts, pstats)


def build_packet(
    xyz: npt.ArrayLike,
    K: npt.ArrayLike,
    T_cam_lidar: npt.ArrayLike,
    hw: tuple[int, int],
    delta_tau_s: float,
    feat: SweepFeatures | npt.NDArray[Any] | torch.Tensor | None,
    *,
    mode: PacketMode = "full",
    model: CameraModel = "pinhole",
    D: npt.ArrayLike | None = None,
    min_depth_m: float = MIN_DEPTH_M,
    front_margin_m: float | None = None,
    c_u: int | None = None,
    patch: int = PATCH_PX,
) -> Packet:
    """Project a sweep (N, 3) into one view and assemble its packet (see `packet_from_support`).

    Pass the same `SweepFeatures` to every view of a sweep: it is validated once, and each view
    reads only its own in-frustum rows. NaN/Inf in any input raises ValueError before pooling.
    """
    spec = _spec(mode)
    require_finite_scalar("delta_tau_s", delta_tau_s)
    pts = np.asarray(xyz, dtype=np.float64)
    sf = _features(feat, pts.shape[0]) if spec.reads_h else None
    sup = view_support(
        pts, K, T_cam_lidar, hw, model=model, D=D, min_depth_m=min_depth_m, patch=patch
    )
    chosen = sf if sf is not None else feat
    return packet_from_support(
        sup, delta_tau_s, chosen, mode=mode, front_margin_m=front_margin_m, c_u=c_u
    )


def _spec(mode: str) -> PacketModeSpec:
    """The behaviour of packet mode `mode`; a DataError naming the modes for any other."""
    if mode not in MODES:
        raise DataError(f"packet mode must be one of {MODES}, got {mode!r}")
    return MODE_SPECS[mode]
