"""Residual LiDAR adapter (paper eq. 11): c~_v = c_v + phi([c_v ; l_v ; r_v]).

phi is a 1x1 conv (C + P + 1 -> 256), SiLU, 1x1 conv (256 -> C) with the final layer
zero-initialized, so at initialization c~_v = c_v exactly (the image-only backbone). For a
target view c_v = 0 (eq. gld-y), so c~_v = phi([0 ; l_v ; 1]).

Packet modes (paper Table "LiDAR input mode"); P is the number of packet channels:
- 'full':      l_v = [g_v ; h_v],            P = n_g + C_u
- 'geom_only': l_v = g_v,                    P = n_g   (Utonia descriptor h never read)
- 'zero':      l_v = 0 of the full shape,    P = n_g + C_u (pathway kept, no content)
- 'learnable': l_v = L, one learned tensor (H, W, n_g + C_u) shared by every view and clip
               (pathway kept and trained, no content; the paper's capacity-matched control)
- 'no_lidar':  no packet channels,           P = 0   (phi sees only [c_v ; r_v])
- 'warp':      l_v = [g_v ; w_v ; m_v],      P = n_g + C + 1
- 'full_warp': l_v = [g_v ; h_v ; w_v ; m_v], P = n_g + C_u + C + 1
  where, on a target view, w_v (C) is the clip's source latents reprojected into v by v's
  packet depth and the cameras (`model.reprojection.warp_latents`, nearest cell, visibility
  by depth order) and m_v its validity (1 where a source filled the cell); both are 0 on
  source views and on cells no source sees. Computed per batch from what the stream yields
  (latents, K, T_world_cam, g), never from a target's own latent.

n_g is the number of explicit channels of schemas.channels (6, eq. 9); each mode's behaviour
is its schemas.modes.PacketModeSpec.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from model.warp_device import warp_channels_device
from packets.reprojection import packet_depth, warp_latents
from schemas.channels import DELTA_TAU, N_G, VALIDITY, channel_index, n_g
from schemas.errors import DataError
from schemas.modes import MODEL_MODES, ModelMode, packet_mode

Mode = ModelMode
MODES: tuple[str, ...] = MODEL_MODES
G_CHANNELS = N_G
"""Explicit statistics channels of eq. 9 (import-time `schemas.channels.n_g()`)."""
DTAU_CHANNEL = channel_index(DELTA_TAU)
"""Index of delta tau (sweep time minus camera time, s) among g's channels (import-time
`schemas.channels.channel_index(DELTA_TAU)`)."""


def packet_channels(mode: str, c_u: int, c: int | None = None) -> int:
    """Number of packet channels P the adapter sees in `mode` (schemas.modes); the warp
    modes need the latent channels c."""
    return packet_mode(mode).channels(c_u, c)


def warp_channels(latents: Tensor, g: Tensor, K: Tensor, T_world_cam: Tensor,
                  is_target: Tensor, image_hw: tuple[int, int]) -> Tensor:
    """Reprojected source latents and their validity, (B, V, H, W, C + 1) channels-last, on
    the latents' device (`model.warp_device.warp_channels_device`, batched in torch; equal
    to `warp_channels_host` within the tolerance pinned in tests/model/test_warp_device.py).
    Arguments as `warp_channels_host`."""
    return warp_channels_device(latents, g, K, T_world_cam, is_target, image_hw)


def warp_channels_host(latents: Tensor, g: Tensor, K: Tensor, T_world_cam: Tensor,
                       is_target: Tensor, image_hw: tuple[int, int]) -> Tensor:
    """Reprojected source latents and their validity, (B, V, H, W, C + 1) channels-last,
    computed on the host in numpy (the reference of the device path).

    latents (B, V, C, H, W) (normalized: nearest reads commute with the per-channel
    normalization); g (B, V, n_g, H, W) packet geometry (its depth and validity); K (B, V, 3, 3)
    in pixels of `image_hw` (h, w); T_world_cam (B, V, 4, 4); is_target (B, V) bool. For each
    target view, `warp_latents` of the clip's source views (float64 geometry); the last
    channel is 1 where a source filled the cell. Source views, and clips without a source, get
    zeros. Dtype and device of `latents`; no gradient flows (the inputs are data).
    """
    B, V, C, H, W = latents.shape
    if tuple(g.shape[-2:]) != (H, W):
        raise DataError(f"warp: g's grid {tuple(g.shape[-2:])} is not the latents' {(H, W)}")
    lat = latents.detach().cpu().double().numpy()
    depth = packet_depth(g.detach().cpu().numpy())  # (B, V, H, W) m, 0 without support
    Ks = K.detach().cpu().double().numpy()
    Ts = T_world_cam.detach().cpu().double().numpy()
    tgt = is_target.detach().cpu().numpy().astype(bool)
    out = np.zeros((B, V, H, W, C + 1), np.float32)
    for b, v in zip(*np.nonzero(tgt), strict=True):
        src = np.flatnonzero(~tgt[b])
        if src.size == 0:
            continue
        w = warp_latents(lat[b, src], depth[b, v], Ks[b, v], Ts[b, v], Ks[b, src], Ts[b, src],
                         depth[b, src], image_hw)
        out[b, v, :, :, :C] = np.moveaxis(w.latent, 0, -1)
        out[b, v, :, :, C] = w.valid
    return torch.from_numpy(out).to(device=latents.device, dtype=latents.dtype)


def warp_for(mode: str, batch: dict[str, Tensor], image_hw: tuple[int, int]) -> Tensor | None:
    """The warp channels (`warp_channels`) of a batch (keys of `model.train_step`) in a warp
    mode, None in any other; a DataError naming what a warp mode's batch lacks."""
    if not packet_mode(mode).warp:
        return None
    missing = [k for k in ("latents", "g", "K", "T_world_cam", "is_target") if k not in batch]
    if missing:
        raise DataError(f"packet mode {mode!r} needs the batch's {', '.join(missing)}")
    return warp_channels(batch["latents"], batch["g"], batch["K"], batch["T_world_cam"],
                         batch["is_target"], image_hw)


def build_packet(mode: str, g: Tensor | None, h: Tensor | None, c_u: int,
                 like: Tensor, learned: Tensor | None = None,
                 warp: Tensor | None = None) -> Tensor | None:
    """Packet l (B, V, H, W, P) float32, channels-last, for `mode`, or None for 'no_lidar'.

    g: (B, V, n_g, H, W) explicit statistics; h: pooled descriptors (only read in 'full'),
    either dense channels-last (B, V, H, W, C_u) or packed as the loader hands them over:
    (K, C_u) rows of the occupied cells (validity channel > 0.5) in (B, V, H, W) row-major order,
    scattered here (unoccupied cells are zero, eq. 10); like: the latents
    (B, V, C, H, W), giving shape, dtype and device for the all-zero packet of 'zero';
    learned: the (H, W, P) tensor of 'learnable', broadcast to every view of every clip;
    warp: the (B, V, H, W, C + 1) warp channels of a warp mode (`warp_for`), appended last.
    Channels-last because phi is a per-cell linear map: h needs no transpose at all.
    """
    spec = packet_mode(mode)
    if spec.warp:
        return _with_warp(mode, build_packet(spec.cache_mode, g, h, c_u, like), warp, like)
    P = spec.channels(c_u)
    if spec.feed == "none":
        return None
    if spec.feed == "zeros":
        B, V, _, H, W = like.shape
        return like.new_zeros(B, V, H, W, P)
    if spec.feed == "learned":
        B, V, _, H, W = like.shape
        if learned is None or learned.shape != (H, W, P):
            raise DataError(f"packet mode {mode!r} needs the learned (H, W, P) = "
                            f"{(H, W, P)} tensor")
        return learned.to(like.dtype).expand(B, V, H, W, P)
    if g is None or (spec.reads_h and h is None):
        raise DataError(f"packet mode {mode!r} needs g{' and h' if spec.reads_h else ''}")
    if g.shape[2] != n_g():
        raise DataError(f"g has {g.shape[2]} channels, expected {n_g()}")
    g_last = g.movedim(2, -1)  # (B, V, H, W, n_g)
    if not spec.reads_h:
        return g_last
    assert h is not None
    if h.ndim == 2:
        h = scatter_rows(h, g[:, :, channel_index(VALIDITY)] > 0.5, g.dtype)
    if h.shape[-1] != c_u or h.shape[2:4] != g.shape[3:5]:
        raise DataError(f"h must be (B, V, H, W, C_u={c_u}) on g's grid {tuple(g.shape[3:])}, "
                         f"got {tuple(h.shape)}")
    return torch.cat([g_last, h.to(g.dtype)], dim=-1)  # (B, V, H, W, n_g + C_u)


def _with_warp(mode: str, ell: Tensor | None, warp: Tensor | None, like: Tensor) -> Tensor:
    """The paper packet ell (B, V, H, W, P0) with the warp channels (B, V, H, W, C + 1) after
    it; a DataError when they are missing or shaped otherwise."""
    B, V, C, H, W = like.shape
    if ell is None or warp is None or tuple(warp.shape) != (B, V, H, W, C + 1):
        got = None if warp is None else tuple(warp.shape)
        raise DataError(f"packet mode {mode!r} needs the warp channels (B, V, H, W, C + 1) = "
                        f"{(B, V, H, W, C + 1)}, got {got}")
    return torch.cat([ell, warp.to(ell.dtype)], dim=-1)


def without_dtau(ell: Tensor) -> Tensor:
    """The packet (B, V, H, W, P) with its delta-tau channel (schemas.channels) zeroed."""
    k = channel_index(DELTA_TAU)
    if ell.shape[-1] <= k:
        return ell
    keep = torch.ones(ell.shape[-1], dtype=ell.dtype, device=ell.device)
    keep[k] = 0
    return ell * keep


def scatter_rows(rows: Tensor, occupied: Tensor, dtype: torch.dtype) -> Tensor:
    """Dense channels-last (*occupied.shape, C_u) of `dtype` from packed rows (K, C_u) of the
    cells `occupied` (bool, row-major order); zero elsewhere."""
    n = int(occupied.sum())
    if rows.shape[0] != n:
        raise ValueError(f"{rows.shape[0]} packed h rows for {n} occupied cells (g's validity)")
    dense = rows.new_zeros((*occupied.shape, rows.shape[1]), dtype=dtype)
    dense[occupied] = rows.to(dtype)
    return dense


class ResidualAdapter(nn.Module):
    """phi of eq. 11 applied per view and per cell (1x1 convolutions)."""

    def __init__(self, c: int, c_u: int, mode: str = "full", hidden: int = 256,
                 grid_hw: tuple[int, int] | None = None) -> None:
        """grid_hw: the latent grid (H, W), needed by 'learnable' for its tensor."""
        super().__init__()
        self.c, self.c_u, self.mode = c, c_u, mode
        self.p = packet_channels(mode, c_u, c)
        self.learned: nn.Parameter | None = None
        if packet_mode(mode).feed == "learned":
            if grid_hw is None:
                raise DataError("packet mode 'learnable' needs the latent grid size")
            # small random start: a zero tensor would make the first steps those of 'zero'
            self.learned = nn.Parameter(0.02 * torch.randn(*grid_hw, self.p))
        # 1x1 convolutions as per-cell linear maps on channels-last tensors (same math; the
        # channels-last matmul beats CPU im2col convolution at C = 1536; docs/benchmarks.md).
        self.conv_in = nn.Linear(c + self.p + 1, hidden)  # 1x1 conv C + P + 1 -> 256
        self.conv_out = nn.Linear(hidden, c)  # 1x1 conv 256 -> C, zero-initialized
        nn.init.zeros_(self.conv_out.weight)
        nn.init.zeros_(self.conv_out.bias)

    def phi(self, x: Tensor) -> Tensor:
        """phi: 1x1 conv, SiLU, 1x1 conv on channels-last cells; x (..., H, W, C + P + 1) ->
        (..., H, W, C)."""
        out: Tensor = self.conv_out(F.silu(self.conv_in(x)))
        return out

    def forward(self, c: Tensor, ell: Tensor | None, r: Tensor) -> Tensor:
        """c~ (B, V, C, H, W) from c (B, V, C, H, W), packet ell (B, V, H, W, P) or None, r (B, V).

        r is the role (1 target, 0 source); target entries of c are zeroed here (c_v = 0).
        """
        B, V, _, H, W = c.shape
        keep = 1.0 - r.to(c.dtype)[:, :, None, None, None]  # (B, V, 1, 1, 1)
        c = c * keep  # c_v = 0 for targets
        if (0 if ell is None else ell.shape[-1]) != self.p:
            raise DataError(f"adapter in mode {self.mode!r} expects {self.p} packet channels")
        r_map = (1.0 - keep).movedim(2, -1).expand(B, V, H, W, 1)  # (B, V, H, W, 1)
        parts = [c.movedim(2, -1)] + ([] if ell is None else [ell.to(c.dtype)])
        x = torch.cat([*parts, r_map], dim=-1)  # (B, V, H, W, C + P + 1): one copy
        delta = self.phi(x).movedim(-1, 2)  # (B, V, C, H, W)
        return c + delta  # c~_v
