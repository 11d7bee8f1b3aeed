"""Plücker rays, cell centres, reference poses, PRoPE matrices."""

from __future__ import annotations

import torch

from model.camera import cell_centres, plucker_rays, projective_matrices, reference_poses, role_map
from tests.model.model_fixtures import GRID, IMAGE, make_batch, random_pose


def test_cell_centres_are_mean_pixel_centres() -> None:
    uv = cell_centres((16, 24), (224, 336))
    assert uv[0, 0].tolist() == [6.5, 6.5]  # mean of pixel centres 0..13
    assert uv[15, 23].tolist() == [23 * 14 + 6.5, 15 * 14 + 6.5]


def test_plucker_unit_direction_and_orthogonal_moment() -> None:
    b = make_batch(B=2, V=3)
    rays = plucker_rays(b["K"], b["T_world_cam"], GRID, IMAGE).double()  # (B, V, 6, H, W)
    d, m = rays[:, :, :3], rays[:, :, 3:]
    assert torch.allclose(d.norm(dim=2), torch.ones(()).double(), atol=1e-6)
    assert (d * m).sum(dim=2).abs().max() < 1e-4
    # moment is o x d with o the camera centre
    o = b["T_world_cam"][:, :, :3, 3][..., None, None]  # (B, V, 3, 1, 1)
    assert torch.allclose(torch.linalg.cross(o.expand_as(d), d, dim=2), m, atol=1e-4)


def test_principal_ray_is_optical_axis() -> None:
    K = torch.tensor([[50.0, 0, 6.5], [0, 50.0, 6.5], [0, 0, 1]])  # principal point = cell centre
    T = random_pose(torch.Generator().manual_seed(3))
    rays = plucker_rays(K, T, (1, 1), (14, 14))  # one cell of 14 px
    assert torch.allclose(rays[:3, 0, 0].double(), T[:3, 2], atol=1e-6)  # camera z axis


def test_reference_poses_first_source_is_identity() -> None:
    b = make_batch(B=2, V=3)
    b["is_target"][1] = torch.tensor([True, False, True])
    T_ref = reference_poses(b["T_world_cam"], b["is_target"])
    eye = torch.eye(4, dtype=torch.float64)
    assert torch.allclose(T_ref[0, 0], eye) and torch.allclose(T_ref[1, 1], eye)
    assert not torch.allclose(T_ref[1, 0], eye)


def test_projective_inverse_and_role_map() -> None:
    b = make_batch()
    P, P_inv = projective_matrices(b["K"], b["T_world_cam"], IMAGE)
    assert torch.allclose(P @ P_inv, torch.eye(4).expand_as(P), atol=1e-4)
    r = role_map(b["is_target"], GRID)
    assert r.shape == (2, 3, 1, *GRID) and r[:, -1].eq(1).all() and r[:, 0].eq(0).all()


def test_cell_centres_are_the_packets_definition() -> None:
    """One definition of the cell centres: the model's are packets' bit for bit."""
    import numpy as np

    from packets.reprojection import cell_centres as packets_cell_centres

    for grid_hw, image_hw in [((16, 24), (224, 336)), ((7, 5), (100, 33)), ((1, 1), (3, 9))]:
        got = cell_centres(grid_hw, image_hw)
        assert got.dtype == torch.float64
        assert np.array_equal(got.numpy(), packets_cell_centres(grid_hw, image_hw))
