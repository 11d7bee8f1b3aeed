"""The warp channels computed on the batch's device: `packets.reprojection` batched in torch.

`warp_channels_device` is `model.adapter.warp_channels_host` (a numpy `warp_latents` call per
target view, on the host, every training step) as one batched torch computation on the
device the latents live on: every (clip, target view, source view) triple at once, no
transfer to the host and no Python loop over targets.

The rules are those of `packets.reprojection` (nearest cell, `MIN_DEPTH_M`, `REL_TOL`):
a supported target cell (packet depth d > 0 m) is lifted to X = T_world_tgt [d K_tgt^-1
(u, v, 1)] at its cell centre (pixels), projected into each source (z-depth, pixels); a
source sees X when z > MIN_DEPTH_M and the pixel lies in [-0.5, w - 0.5] x [-0.5, h - 0.5]
(edges included); a source whose own packet depth at the nearest cell lies in front of X by
more than REL_TOL of z is occluded; the remaining sources rank confirmed (|own - z| <=
REL_TOL z) before unknown, then by z, then by the lowest view index.

Geometry runs in float64 (float32 where the device has no float64, e.g. MPS); the latents
are gathered in their own dtype, never rounded. Against the host path (pinned by
tests/model/test_warp_device.py): the chosen source and validity agree cell for cell in
float64 geometry, and the warped latents are equal, except that the host path rounds
float64 latents through float32 (relative difference <= 2**-24).
"""

from __future__ import annotations

import torch
from torch import Tensor

from packets.reprojection import G_INV_DEPTH, MIN_DEPTH_M, REL_TOL, cell_centres
from schemas.errors import DataError
from schemas.packed_cells import VALID_CHANNEL


def geometry_dtype(device: torch.device) -> torch.dtype:
    """float64, or float32 on a device without float64 arithmetic (MPS)."""
    return torch.float32 if device.type == "mps" else torch.float64


def packet_depth_t(g: Tensor, dtype: torch.dtype = torch.float64) -> Tensor:
    """Per-cell mean depth (..., H, W) m of packet geometry g (..., n_g, H, W) in `dtype`; 0
    without support (validity <= 0.5, a non-positive or non-finite inverse depth), as
    `packets.reprojection.packet_depth`."""
    a = g.to(dtype)
    inv = a[..., G_INV_DEPTH, :, :]
    ok = (a[..., VALID_CHANNEL, :, :] > 0.5) & torch.isfinite(inv) & (inv > 0)
    return torch.where(ok, 1.0 / torch.where(ok, inv, 1.0), 0.0)


def _apply(M: Tensor, x: Tensor) -> Tensor:
    """M x for matrices M (..., 3, 3) and vectors x (..., 3) (broadcast) -> (..., 3)."""
    return (M * x.unsqueeze(-2)).sum(-1)


def _source_view(depth: Tensor, K: Tensor, T: Tensor, image_hw: tuple[int, int]
                 ) -> tuple[Tensor, Tensor, Tensor]:
    """Every view's cells projected into every view of its clip.

    depth (B, V, H, W) m; K (B, V, 3, 3) px; T (B, V, 4, 4) T_world_cam, all one float dtype.
    Returns, indexed (B, V_target, V_source, H, W): z the point's depth in the source (m; inf
    where the target cell is unsupported), inside (in front and inside the source image),
    cell the flat index row * W + col of the nearest source cell (int64, clipped to the grid).
    """
    H, W = depth.shape[-2:]
    dt, dev = depth.dtype, depth.device
    nan = float("nan")
    supported = torch.isfinite(depth) & (depth > 0)  # (B, V, H, W)
    uv = torch.from_numpy(cell_centres((H, W), image_hw)).to(device=dev, dtype=dt)  # (H, W, 2)
    pix = torch.cat([uv, torch.ones_like(uv[..., :1])], dim=-1)  # (H, W, 3)
    K_inv = torch.linalg.inv_ex(K)[0]  # no singularity check: no device-to-host sync
    rays = _apply(K_inv[:, :, None, None], pix)  # (B, V, H, W, 3), z = 1
    cam = rays * torch.where(supported, depth, nan)[..., None]
    R, t = T[..., :3, :3], T[..., :3, 3]
    X = _apply(R[:, :, None, None], cam) + t[:, :, None, None]  # (B, V, H, W, 3) world
    # into each source s: R_s^T (X - t_s), indexed (B, V_t, V_s, H, W, 3)
    rel = X[:, :, None] - t[:, None, :, None, None]
    cam_s = _apply(R.transpose(-1, -2)[:, None, :, None, None], rel)
    z = cam_s[..., 2]
    pix_s = _apply(K[:, None, :, None, None], cam_s)
    uv_s = pix_s[..., :2] / torch.where(z > 0, z, nan)[..., None]  # (..., 2) (u, v) px
    sup = supported[:, :, None]
    (h, w), u, v = image_hw, uv_s[..., 0], uv_s[..., 1]
    in_image = (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)  # NaN: outside
    inside = sup & torch.isfinite(z) & (z > MIN_DEPTH_M) & in_image
    # nearest cell floor(c + 0.5) of the continuous cell c, clipped (scalars only: no copy
    # from the host, hence no synchronization, on a GPU)
    col = torch.nan_to_num((u + 0.5) * (W / w) - 0.5, nan=0.0)
    row = torch.nan_to_num((v + 0.5) * (H / h) - 0.5, nan=0.0)
    cell = (torch.clamp(torch.floor(row + 0.5), 0, H - 1).long() * W
            + torch.clamp(torch.floor(col + 0.5), 0, W - 1).long())
    z_rank = torch.nan_to_num(torch.where(sup, z, nan), nan=float("inf"))
    return z_rank, inside, cell


def choose_sources_t(depth: Tensor, z: Tensor, inside: Tensor, cell: Tensor,
                     is_source: Tensor, rel_tol: float = REL_TOL) -> Tensor:
    """Per (clip, view, cell) the source view to read, (B, V, H, W) int64, -1 where none.

    depth (B, V, H, W) packet depths (m, 0: no support); z, inside (B, V_t, V_s, H, W) from
    `_source_view`; cell (B, V_t, V_s, H, W) the flat index row * W + col of the nearest
    source cell; is_source (B, V) the views that may be read. Ranking of
    `packets.reprojection.choose_sources`: occluded dropped; confirmed, then unknown; then
    smallest z; then lowest view index.
    """
    B, V, H, W = depth.shape
    src_d = depth.reshape(B, 1, V, H * W).expand(B, V, V, H * W)
    own = torch.gather(src_d, 3, cell.reshape(B, V, V, H * W)).reshape(z.shape)
    known = torch.isfinite(own) & (own > 0)
    occluded = known & (own < z * (1.0 - rel_tol))
    confirmed = known & ((own - z).abs() <= rel_tol * z)
    usable = inside & ~occluded & is_source[:, None, :, None, None]
    # rank 0 confirmed, 1 unknown, 2 unusable; the best rank first, then the smallest z
    rank = 2 - usable.to(torch.uint8) - (usable & confirmed).to(torch.uint8)
    cand = rank == rank.amin(dim=2, keepdim=True)
    zc = torch.where(cand, z, float("inf"))
    cand = cand & (zc == zc.amin(dim=2, keepdim=True))
    first = torch.argmax(cand.to(torch.uint8), dim=2)  # the lowest index among the ties
    return torch.where(usable.any(dim=2), first, -1)


@torch.no_grad()
def warp_channels_device(latents: Tensor, g: Tensor, K: Tensor, T_world_cam: Tensor,
                         is_target: Tensor, image_hw: tuple[int, int],
                         rel_tol: float = REL_TOL, compact: bool | None = None,
                         geometry: torch.dtype | None = None) -> Tensor:
    """Reprojected source latents and their validity, (B, V, H, W, C + 1) channels-last.

    latents (B, V, C, H, W); g (B, V, n_g, H, W) packet geometry (depth and validity);
    K (B, V, 3, 3) px of `image_hw` (h, w); T_world_cam (B, V, 4, 4) m; is_target (B, V)
    bool. On each target view, its clip's source views warped in by the target's packet
    depth (module doc); the last channel is 1 where a source filled the cell. Source views,
    cells no source sees and clips without a source are 0. Dtype and device of `latents`.
    compact: read the latents of the target views only, found on the host (a device sync);
    None: on the CPU only, where the sync is free and the source views' rows (zeros) are
    the bulk of the memory traffic. Both give the same result. geometry: the dtype of the
    depths, cameras and projections (None: `geometry_dtype` of the device).
    """
    B, V, C, H, W = latents.shape
    if tuple(g.shape[-2:]) != (H, W):
        raise DataError(f"warp: g's grid {tuple(g.shape[-2:])} is not the latents' {(H, W)}")
    dev = latents.device
    dt = geometry or geometry_dtype(dev)
    tgt = is_target.to(dev, torch.bool)
    depth = packet_depth_t(g.to(dev), dt)  # (B, V, H, W)
    z, inside, cell = _source_view(depth, K.to(dev, dt), T_world_cam.to(dev, dt), image_hw)
    chosen = choose_sources_t(depth, z, inside, cell, ~tgt, rel_tol)
    valid = (chosen >= 0) & tgt[:, :, None, None]  # (B, V, H, W)
    s = chosen.clamp(min=0)
    at = torch.gather(cell, 2, s[:, :, None]).squeeze(2)  # (B, V, H, W) flat source cell
    if compact is None:
        compact = dev.type == "cpu"
    lat = latents.detach().flatten(3)  # (B, V, C, H*W)
    if compact:  # the target views' rows only (their count is read: a sync off the host)
        out = latents.new_zeros(B, V, H * W, C + 1)
        bt, vt = torch.nonzero(tgt, as_tuple=True)
        ok = valid[bt, vt].flatten(1)  # (n, H*W)
        rows = lat[bt[:, None], s[bt, vt].flatten(1), :, at[bt, vt].flatten(1)]  # (n, H*W, C)
        out[bt, vt, :, :C] = rows.masked_fill_(~ok[..., None], 0.0)
        out[bt, vt, :, C] = ok.to(latents.dtype)
        return out.reshape(B, V, H, W, C + 1)
    clip = torch.arange(B, device=dev)[:, None, None]
    # one read per (clip, view, cell): (B, V, H*W, C), channels-last
    rows = lat[clip, s.flatten(2), :, at.flatten(2)]
    rows.masked_fill_(~valid.flatten(2)[..., None], 0.0)
    out = torch.cat([rows, valid.flatten(2)[..., None].to(latents.dtype)], dim=-1)
    return out.reshape(B, V, H, W, C + 1)
