"""PRoPE attention: projective relative positional encoding (Li et al. 2025,
"Cameras as Relative Positional Encoding").

Each token i of view v carries a transform D_i = blockdiag(P_v, ..., P_v, R_i) acting on its
head vector: P_v = [[K_v, 0], [0, 1]] T_cam_world,v (4x4) on 4-channel chunks of the first half
of the head dims, and R_i a 2D RoPE rotation by the token's patch (row, col) on the second half.
Attention uses q'_i = D_i^T q_i, k'_j = D_j^-1 k_j, v'_j = D_j^-1 v_j and returns
o_i = D_i sum_j softmax(q'_i . k'_j) v'_j, so every score depends on cameras only through the
relative projective transform P_vi P_vj^-1 and on positions only through (row, col) differences.
A global rigid (indeed any invertible) change of world frame cancels exactly.

Same structure as the authors' reference: half of each head's channels projective (P tiled
over 4-channel chunks), a quarter RoPE over the patch column, a quarter over the row, RoPE
frequency base 100. Simplifications/differences: interleaved RoPE pairs (a fixed channel
permutation of their split layout), intrinsics normalized so the image spans [-1, 1] (theirs
[-0.5, 0.5]; see `model.camera.projective_matrices`), P^-1 by a general 4x4 inverse, no
register-token masking, and poses expressed relative to the first source camera upstream.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from schemas.errors import DataError


def split_head_dim(head_dim: int) -> tuple[int, int]:
    """(projective dims, RoPE dims) of one head; head_dim must be a multiple of 8."""
    if head_dim % 8:
        raise DataError(f"PRoPE needs head_dim divisible by 8, got {head_dim}")
    return head_dim // 2, head_dim // 2


def rope_angles(grid_hw: tuple[int, int], rope_dims: int, base: float = 100.0) -> Tensor:
    """Rotation angles (N, rope_dims // 2) for N = H * W tokens in row-major order.

    The first half of the pairs rotates with the column index, the second with the row.
    """
    gh, gw = grid_hw
    n_pairs = rope_dims // 4  # pairs per axis
    freqs = base ** (-torch.arange(n_pairs, dtype=torch.float64) / max(n_pairs, 1))  # (n_pairs,)
    rows, cols = torch.meshgrid(torch.arange(gh), torch.arange(gw), indexing="ij")
    ang_x = cols.reshape(-1, 1).double() * freqs  # (N, n_pairs)
    ang_y = rows.reshape(-1, 1).double() * freqs  # (N, n_pairs)
    return torch.cat([ang_x, ang_y], dim=1).float()  # (N, rope_dims // 2)


def rotate(x: Tensor, angles: Tensor) -> Tensor:
    """Rotate consecutive channel pairs of x (..., N, 2 * A) by angles (N, A)."""
    x2 = x.reshape(*x.shape[:-1], -1, 2)  # (..., N, A, 2)
    cos, sin = angles.cos().to(x.dtype), angles.sin().to(x.dtype)  # (N, A)
    a, b = x2[..., 0], x2[..., 1]
    return torch.stack([a * cos - b * sin, a * sin + b * cos], dim=-1).flatten(-2)


def apply_blocks(M: Tensor, x: Tensor) -> Tensor:
    """y = M_n x per 4-channel chunk: M (B, N, 4, 4), x (B, heads, N, 4G) -> (B, heads, N, 4G)."""
    x4 = x.reshape(*x.shape[:-1], -1, 4)  # (B, h, N, G, 4)
    return torch.einsum("bnij,bhngj->bhngi", M.to(x.dtype), x4).flatten(-2)


def prope_attention(q: Tensor, k: Tensor, v: Tensor, P: Tensor, P_inv: Tensor,
                    angles: Tensor) -> Tensor:
    """Multi-view attention with PRoPE.

    q, k, v: (B, heads, N, head_dim) for N tokens over all views; P, P_inv: (B, N, 4, 4) each
    token's view matrix and inverse; angles: (N, head_dim // 4) RoPE angles per token.
    Returns (B, heads, N, head_dim).
    """
    dp, _ = split_head_dim(q.shape[-1])
    P_T = P.transpose(-1, -2)  # (B, N, 4, 4)
    q_ = torch.cat([apply_blocks(P_T, q[..., :dp]), rotate(q[..., dp:], -angles)], dim=-1)
    k_ = torch.cat([apply_blocks(P_inv, k[..., :dp]), rotate(k[..., dp:], -angles)], dim=-1)
    v_ = torch.cat([apply_blocks(P_inv, v[..., :dp]), rotate(v[..., dp:], -angles)], dim=-1)
    o_ = F.scaled_dot_product_attention(q_, k_, v_)  # (B, h, N, hd)
    return torch.cat([apply_blocks(P, o_[..., :dp]), rotate(o_[..., dp:], angles)], dim=-1)
