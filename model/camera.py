"""Camera conditioning on the latent grid: Plücker ray maps, role maps, projective matrices.

Conventions: OpenCV cameras (x right, y down, z forward); `T_a_b` maps frame b into frame a;
pixel centres sit at integer pixel coordinates, so latent cell (i, j) of a `patch`-pixel grid
has its centre at pixel ((j + 0.5) * patch - 0.5, (i + 0.5) * patch - 0.5), the mean of the
pixel centres it covers (same cell assignment as `packets.support.cell_ids`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from packets import reprojection


def cell_centres(grid_hw: tuple[int, int], image_hw: tuple[int, int]) -> Tensor:
    """Pixel coordinates (u, v) of latent cell centres, float64 (H, W, 2), in image pixels
    (`packets.reprojection.cell_centres`, the one definition)."""
    return torch.from_numpy(reprojection.cell_centres(grid_hw, image_hw))


def plucker_rays(K: Tensor, T_world_cam: Tensor, grid_hw: tuple[int, int],
                 image_hw: tuple[int, int]) -> Tensor:
    """Per-cell Plücker map [d, o x d] (..., 6, H, W), float32.

    K: (..., 3, 3) intrinsics in pixels of an `image_hw` image; T_world_cam: (..., 4, 4),
    translation in metres. d is the unit ray direction in the world frame through the cell
    centre, o the camera centre in the world frame, m = o x d the moment (metres).
    Computed in float64.
    """
    uv = cell_centres(grid_hw, image_hw).to(K.device)  # (H, W, 2)
    pix = torch.cat([uv, torch.ones_like(uv[..., :1])], dim=-1)  # (H, W, 3) homogeneous
    K_inv = torch.linalg.inv(K.double())  # (..., 3, 3)
    R = T_world_cam[..., :3, :3].double()  # (..., 3, 3)
    o = T_world_cam[..., :3, 3].double()  # (..., 3)
    d_cam = torch.einsum("...ij,hwj->...hwi", K_inv, pix)  # (..., H, W, 3)
    d = torch.einsum("...ij,...hwj->...hwi", R, d_cam)  # (..., H, W, 3)
    d = d / d.norm(dim=-1, keepdim=True)
    o = o[..., None, None, :].expand_as(d)  # (..., H, W, 3)
    m = torch.linalg.cross(o, d, dim=-1)  # (..., H, W, 3)
    rays = torch.cat([d, m], dim=-1)  # (..., H, W, 6)
    return rays.movedim(-1, -3).float()  # (..., 6, H, W)


def role_map(is_target: Tensor, grid_hw: tuple[int, int]) -> Tensor:
    """Role channel r_v broadcast over the grid: (..., 1, H, W) float32, 1 target, 0 source."""
    r = is_target.float()[..., None, None, None]  # (..., 1, 1, 1)
    return r.expand(*is_target.shape, 1, *grid_hw)


def nearest_source_views(T_world_cam: Tensor, is_target: Tensor) -> Tensor:
    """Per view, the index of the clip's source view whose camera centre is nearest (B, V) int64.

    T_world_cam (B, V, 4, 4), is_target (B, V) bool. A source view maps to itself; distances
    in float64; ties go to the lowest index. Raises ValueError if a clip has no source view.
    """
    centres = T_world_cam[..., :3, 3].double()  # (B, V, 3)
    d = (centres[:, :, None, :] - centres[:, None, :, :]).norm(dim=-1)  # (B, V, V)
    d = d.masked_fill(is_target[:, None, :], float("inf"))
    if not bool((~is_target).any(dim=1).all()):
        raise ValueError("nearest source: a clip has no source view")
    nearest: Tensor = d.argmin(dim=2)
    return nearest


def reference_poses(T_world_cam: Tensor, is_target: Tensor) -> Tensor:
    """Poses T_ref_cam (B, V, 4, 4) relative to each clip's first source camera.

    Expressing rays in this frame makes the camera conditioning invariant to a global rigid
    transform of the world (a common choice in multi-view diffusion). A clip with no source
    view uses its first view as reference. Computed in float64.
    """
    T = T_world_cam.double()  # (B, V, 4, 4)
    ref = torch.argmax((~is_target).to(torch.int64), dim=1)  # (B,) first source (0 if none)
    T_world_ref = T[torch.arange(T.shape[0], device=T.device), ref]  # (B, 4, 4)
    T_ref_cam: Tensor = torch.linalg.inv(T_world_ref)[:, None] @ T  # (B, V, 4, 4)
    return T_ref_cam


def projective_matrices(K: Tensor, T_world_cam: Tensor,
                        image_hw: tuple[int, int]) -> tuple[Tensor, Tensor]:
    """PRoPE camera matrices P = [[K_n, 0], [0, 1]] @ T_cam_world and P^-1, (..., 4, 4) float32.

    K_n is K with pixels rescaled so the image spans [-1, 1] in both axes (keeps entries O(1));
    computed in float64, then cast.
    """
    h, w = image_hw
    S = torch.tensor([[2.0 / w, 0.0, 1.0 / w - 1.0],  # maps pixel u in [-0.5, w-0.5] to [-1, 1]
                      [0.0, 2.0 / h, 1.0 / h - 1.0],
                      [0.0, 0.0, 1.0]], dtype=torch.float64, device=K.device)
    K4 = torch.zeros(*K.shape[:-2], 4, 4, dtype=torch.float64, device=K.device)
    K4[..., :3, :3] = S @ K.double()
    K4[..., 3, 3] = 1.0
    P = K4 @ torch.linalg.inv(T_world_cam.double())  # (..., 4, 4)
    return P.float(), torch.linalg.inv(P).float()
