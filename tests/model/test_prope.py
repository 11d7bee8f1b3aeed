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
