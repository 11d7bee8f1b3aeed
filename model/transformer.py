"""Multi-view flow transformer v_theta(z_t, t, y) (DiT-style, adaLN-Zero), GLD backbone shape.

Per view v the input is [c~_v ; z_t,v] (2C channels on the H x W latent grid), patch-embedded
into tokens; the camera map [Plücker d, o x d ; r_v] (7 channels) is patch-embedded and added,
with a fixed 2D sin-cos position embedding. All V views' tokens attend jointly (multi-view
self-attention), optionally with PRoPE (`model.prope`). The flow time t conditions every block
through adaLN-Zero. Output: velocity (B, V, C, H, W).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from model.prope import prope_attention, rope_angles, split_head_dim
from schemas.errors import DataError


@dataclass(frozen=True)
class TransformerConfig:
    """Backbone sizes. width D, depth (blocks), heads, patch p (cells per token side)."""

    width: int = 128
    depth: int = 4
    heads: int = 4
    patch: int = 2
    mlp_ratio: float = 4.0
    prope: bool = True


PRESETS: dict[str, TransformerConfig] = {
    "tiny": TransformerConfig(width=128, depth=4, heads=4, patch=2),
    "gld": TransformerConfig(width=1152, depth=28, heads=16, patch=1),  # DiT-XL sized
}


def timestep_embedding(t: Tensor, dim: int, max_period: float = 10000.0) -> Tensor:
    """Sinusoidal embedding (B, dim) of flow time t (B,) in [0, 1] (scaled by 1000 as in DiT)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=t.device) / half)
    args = 1000.0 * t.float()[:, None] * freqs[None]  # (B, half)
    return torch.cat([torch.cos(args), torch.sin(args)], dim=-1)


def sincos_2d(grid_hw: tuple[int, int], dim: int) -> Tensor:
    """Fixed 2D sin-cos position embedding (H * W, dim), row-major; dim divisible by 4."""
    gh, gw = grid_hw
    q = dim // 4
    omega = 1.0 / 10000 ** (torch.arange(q, dtype=torch.float64) / q)  # (q,)
    rows, cols = torch.meshgrid(torch.arange(gh), torch.arange(gw), indexing="ij")
    oy = rows.reshape(-1, 1).double() * omega  # (N, q)
    ox = cols.reshape(-1, 1).double() * omega
    return torch.cat([oy.sin(), oy.cos(), ox.sin(), ox.cos()], dim=1).float()  # (N, dim)


def modulate(x: Tensor, shift: Tensor, scale: Tensor) -> Tensor:
    """adaLN modulation x (B, N, D) with shift, scale (B, D)."""
    return x * (1 + scale[:, None]) + shift[:, None]


class Block(nn.Module):
    """Pre-norm transformer block with adaLN-Zero (gates zero at init)."""

    def __init__(self, cfg: TransformerConfig) -> None:
        super().__init__()
        D = cfg.width
        self.heads, self.use_prope = cfg.heads, cfg.prope
        self.norm1 = nn.LayerNorm(D, elementwise_affine=False, eps=1e-6)
        self.qkv = nn.Linear(D, 3 * D)
        self.proj = nn.Linear(D, D)
        self.norm2 = nn.LayerNorm(D, elementwise_affine=False, eps=1e-6)
        hidden = int(D * cfg.mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(D, hidden), nn.GELU(approximate="tanh"),
                                 nn.Linear(hidden, D))
        self.ada = nn.Linear(D, 6 * D)  # adaLN-Zero modulation, zero-initialized
        nn.init.zeros_(self.ada.weight)
        nn.init.zeros_(self.ada.bias)

    def attend(self, x: Tensor, P: Tensor | None, P_inv: Tensor | None,
               angles: Tensor | None) -> Tensor:
        """Joint self-attention over all N = V * tokens-per-view tokens: x (B, N, D)."""
        B, N, D = x.shape
        q, k, v = self.qkv(x).reshape(B, N, 3, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        if self.use_prope and P is not None and P_inv is not None and angles is not None:
            o = prope_attention(q, k, v, P, P_inv, angles)  # (B, h, N, hd)
        else:
            o = F.scaled_dot_product_attention(q, k, v)  # (B, h, N, hd)
        out: Tensor = self.proj(o.transpose(1, 2).reshape(B, N, D))
        return out

    def forward(self, x: Tensor, c: Tensor, P: Tensor | None, P_inv: Tensor | None,
                angles: Tensor | None) -> Tensor:
        """x (B, N, D) tokens, c (B, D) time conditioning -> (B, N, D)."""
        s1, sc1, g1, s2, sc2, g2 = self.ada(F.silu(c)).chunk(6, dim=-1)  # 6 x (B, D)
        x = x + g1[:, None] * self.attend(modulate(self.norm1(x), s1, sc1), P, P_inv, angles)
        out: Tensor = x + g2[:, None] * self.mlp(modulate(self.norm2(x), s2, sc2))
        return out


class MultiViewDiT(nn.Module):
    """v_theta over V views of C-channel latents on an (H, W) grid."""

    def __init__(self, c: int, grid_hw: tuple[int, int], cfg: TransformerConfig) -> None:
        super().__init__()
        p, D = cfg.patch, cfg.width
        if grid_hw[0] % p or grid_hw[1] % p:
            raise DataError(f"grid {grid_hw} not divisible by patch {p}")
        if cfg.prope:
            split_head_dim(D // cfg.heads)
        self.c, self.grid_hw, self.cfg = c, grid_hw, cfg
        self.tok_hw = (grid_hw[0] // p, grid_hw[1] // p)
        self.x_embed = nn.Conv2d(2 * c, D, kernel_size=p, stride=p)  # [c~ ; z_t] -> tokens
        self.cam_embed = nn.Conv2d(7, D, kernel_size=p, stride=p)  # [Plücker ; r] -> tokens
        self.t_embed = nn.Sequential(nn.Linear(256, D), nn.SiLU(), nn.Linear(D, D))
        self.pos: Tensor
        self.angles: Tensor
        self.register_buffer("pos", sincos_2d(self.tok_hw, D), persistent=False)  # (n, D)
        angles = rope_angles(self.tok_hw, (D // cfg.heads) // 2) if cfg.prope else torch.empty(0)
        self.register_buffer("angles", angles, persistent=False)  # (n, head_dim // 4)
        self.blocks = nn.ModuleList(Block(cfg) for _ in range(cfg.depth))
        self.norm_out = nn.LayerNorm(D, elementwise_affine=False, eps=1e-6)
        self.ada_out = nn.Linear(D, 2 * D)
        self.out = nn.Linear(D, p * p * c)
        for lin in (self.ada_out, self.out):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)

    def forward(self, x: Tensor, cam: Tensor, t: Tensor, P: Tensor | None = None,
                P_inv: Tensor | None = None) -> Tensor:
        """Velocity (B, V, C, H, W).

        x: [c~ ; z_t] (B, V, 2C, H, W); cam: [Plücker ; r] (B, V, 7, H, W); t: (B,) in [0, 1];
        P, P_inv: (B, V, 4, 4) PRoPE camera matrices (ignored unless cfg.prope).
        """
        B, V = x.shape[:2]
        n = self.tok_hw[0] * self.tok_hw[1]
        tok = self.x_embed(x.flatten(0, 1)) + self.cam_embed(cam.flatten(0, 1))  # (BV, D, h, w)
        tok = tok.flatten(2).transpose(1, 2) + self.pos  # (BV, n, D)
        tok = tok.reshape(B, V * n, -1)  # (B, N, D), N = V n
        c = self.t_embed(timestep_embedding(t, 256))  # (B, D)
        Pt = Pit = ang = None
        if self.cfg.prope and P is not None and P_inv is not None:
            Pt = P.repeat_interleave(n, dim=1)  # (B, N, 4, 4)
            Pit = P_inv.repeat_interleave(n, dim=1)
            ang = self.angles.repeat(V, 1)  # (N, hd // 4)
        for blk in self.blocks:
            tok = blk(tok, c, Pt, Pit, ang)  # (B, N, D)
        shift, scale = self.ada_out(F.silu(c)).chunk(2, dim=-1)
        y = self.out(modulate(self.norm_out(tok), shift, scale))  # (B, N, p p C)
        return self.unpatchify(y, B, V)

    def unpatchify(self, y: Tensor, B: int, V: int) -> Tensor:
        """Tokens (B, V n, p p C) -> grid (B, V, C, H, W)."""
        p, (h, w) = self.cfg.patch, self.tok_hw
        y = y.reshape(B, V, h, w, p, p, self.c)
        return torch.einsum("bvhwpqc->bvchpwq", y).reshape(B, V, self.c, h * p, w * p)
