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

n_g is the number of explicit channels of schemas.channels (6, eq. 9); each mode's behaviour
is its schemas.modes.PacketModeSpec.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from schemas.channels import DELTA_TAU, N_G, VALIDITY, channel_index, n_g
from schemas.errors import DataError
from schemas.modes import PACKET_MODES, PacketMode, packet_mode

Mode = PacketMode
MODES: tuple[str, ...] = PACKET_MODES
G_CHANNELS = N_G
"""Explicit statistics channels of eq. 9 (import-time `schemas.channels.n_g()`)."""
DTAU_CHANNEL = channel_index(DELTA_TAU)
"""Index of delta tau (sweep time minus camera time, s) among g's channels (import-time
`schemas.channels.channel_index(DELTA_TAU)`)."""


def packet_channels(mode: str, c_u: int) -> int:
    """Number of packet channels P the adapter sees in `mode` (schemas.modes)."""
    return packet_mode(mode).channels(c_u)


def build_packet(mode: str, g: Tensor | None, h: Tensor | None, c_u: int,
                 like: Tensor, learned: Tensor | None = None) -> Tensor | None:
    """Packet l (B, V, H, W, P) float32, channels-last, for `mode`, or None for 'no_lidar'.

    g: (B, V, n_g, H, W) explicit statistics; h: pooled descriptors (only read in 'full'),
    either dense channels-last (B, V, H, W, C_u) or packed as the loader hands them over:
    (K, C_u) rows of the occupied cells (validity channel > 0.5) in (B, V, H, W) row-major order,
    scattered here (unoccupied cells are zero, eq. 10); like: the latents
    (B, V, C, H, W), giving shape, dtype and device for the all-zero packet of 'zero';
    learned: the (H, W, P) tensor of 'learnable', broadcast to every view of every clip.
    Channels-last because phi is a per-cell linear map: h needs no transpose at all.
    """
    spec = packet_mode(mode)
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
        self.p = packet_channels(mode, c_u)
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
