"""PRoPE: invariance to the world frame, reduction to attention, sensitivity to cameras."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from model.camera import projective_matrices
from model.prope import prope_attention, rope_angles
from tests.model.model_fixtures import IMAGE, make_batch, random_pose


def _inputs(seed: int = 0) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(seed)
    B, h, V, n, hd = 2, 2, 3, 6, 16
    q, k, v = (torch.randn(B, h, V * n, hd, generator=gen, dtype=torch.float64) for _ in range(3))
    return q, k, v, torch.tensor(n)


def _cams(T: torch.Tensor, K: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    P, P_inv = projective_matrices(K, T, IMAGE)
    return P.double().repeat_interleave(n, 1), P_inv.double().repeat_interleave(n, 1)


def test_invariant_to_global_rigid_transform() -> None:
    q, k, v, n = _inputs()
    b = make_batch(B=2, V=3)
    ang = rope_angles((2, 3), 8).repeat(3, 1).double()
    out = prope_attention(q, k, v, *_cams(b["T_world_cam"], b["K"], int(n)), ang)
    G = random_pose(torch.Generator().manual_seed(9), scale=5.0)
    out_g = prope_attention(q, k, v, *_cams(G @ b["T_world_cam"], b["K"], int(n)), ang)
    assert torch.allclose(out, out_g, atol=1e-4, rtol=1e-4)
    # moving one camera relative to the others changes the result
    T2 = b["T_world_cam"].clone()
    T2[:, 1] = G @ T2[:, 1]
    out_2 = prope_attention(q, k, v, *_cams(T2, b["K"], int(n)), ang)
    assert (out - out_2).abs().max() > 1e-3


def test_identity_cameras_zero_angles_is_plain_attention() -> None:
    q, k, v, _ = _inputs(1)
    N = q.shape[2]
    eye = torch.eye(4, dtype=torch.float64).expand(2, N, 4, 4)
    out = prope_attention(q, k, v, eye, eye, torch.zeros(N, 4, dtype=torch.float64))
    assert torch.allclose(out, F.scaled_dot_product_attention(q, k, v), atol=1e-10)


def _grid_angles(rows: torch.Tensor, cols: torch.Tensor, rope_dims: int) -> torch.Tensor:
    """RoPE angles (N, rope_dims // 2) of tokens at (rows, cols), read off `rope_angles`."""
    big = rope_angles((int(rows.max()) + 1, int(cols.max()) + 1), rope_dims).double()
    return big[rows * (int(cols.max()) + 1) + cols]


def _token_grid(V: int, gh: int, gw: int) -> tuple[torch.Tensor, torch.Tensor]:
    rows, cols = torch.meshgrid(torch.arange(gh), torch.arange(gw), indexing="ij")
    return rows.reshape(-1).repeat(V), cols.reshape(-1).repeat(V)  # (V * gh * gw,)


def test_rope_angles_follow_column_then_row() -> None:
    ang = rope_angles((2, 3), 8)  # 2 pairs per axis: columns first, then rows
    freqs = torch.tensor([1.0, 100.0 ** -0.5])
    rows, cols = _token_grid(1, 2, 3)
    expect = torch.cat([cols[:, None] * freqs, rows[:, None] * freqs], dim=1)
    assert torch.allclose(ang, expect, atol=1e-6)


def test_rope_half_sees_only_relative_positions() -> None:
    q, k, v, n = _inputs(2)
    b = make_batch(B=2, V=3)
    cams = _cams(b["T_world_cam"], b["K"], int(n))
    rows, cols = _token_grid(3, 2, 3)  # V = 3 views of 2 x 3 tokens
    ang = _grid_angles(rows, cols, 8)
    out = prope_attention(q, k, v, *cams, ang)
    # the same shift of every token's (row, col) cancels in q'.k' and in D_i ... D_j^-1 v_j
    for dr, dc in ((0, 5), (4, 0), (3, 7)):
        shifted = prope_attention(q, k, v, *cams, _grid_angles(rows + dr, cols + dc, 8))
        assert torch.allclose(out, shifted, atol=1e-9), (dr, dc)
    # but positions do matter: zero angles or permuted positions change the output
    zero = prope_attention(q, k, v, *cams, torch.zeros_like(ang))
    assert (out - zero).abs().max() > 1e-2
    assert (out[..., :8] - zero[..., :8]).abs().max() > 1e-3  # via the scores, too
    swapped = prope_attention(q, k, v, *cams, _grid_angles(cols.remainder(2), rows, 8))
    assert (out - swapped).abs().max() > 1e-2


def _rot(theta: torch.Tensor) -> torch.Tensor:
    """Block-diagonal rotation (2A, 2A) by angles (A,) on consecutive channel pairs."""
    c, s = theta.cos(), theta.sin()
    return torch.block_diag(*[torch.tensor([[ci, -si], [si, ci]], dtype=torch.float64)
                              for ci, si in zip(c.tolist(), s.tolist(), strict=True)])


def test_matches_explicit_per_token_transform() -> None:
    """o_i = D_i sum_j softmax_j((D_i^T q_i) . (D_j^-1 k_j) / sqrt(d)) D_j^-1 v_j, by hand."""
    q, k, v, n = _inputs(3)
    b = make_batch(B=2, V=3, seed=4)
    P, P_inv = _cams(b["T_world_cam"], b["K"], int(n))
    rows, cols = _token_grid(3, 2, 3)
    ang = _grid_angles(rows, cols, 8)
    out = prope_attention(q, k, v, P, P_inv, ang)
    B, H, N, hd = q.shape
    expect = torch.empty_like(out)
    for bi in range(B):
        D = torch.stack([torch.block_diag(P[bi, i], P[bi, i], _rot(ang[i])) for i in range(N)])
        D_inv = torch.linalg.inv(D)
        for h in range(H):
            qp = torch.einsum("nji,nj->ni", D, q[bi, h])  # D_i^T q_i
            kp = torch.einsum("nij,nj->ni", D_inv, k[bi, h])
            vp = torch.einsum("nij,nj->ni", D_inv, v[bi, h])
            w = torch.softmax(qp @ kp.T / hd**0.5, dim=-1)  # (N, N)
            expect[bi, h] = torch.einsum("nij,nj->ni", D, w @ vp)
    assert torch.allclose(out, expect, atol=1e-8)
