"""M3GD network: residual adapter (eq. 11) + camera conditioning + multi-view transformer.

`condition()` builds everything of y that does not depend on (z_t, t): c~ (the adapter, run
once per query), the camera map and PRoPE matrices. `velocity()` evaluates v_theta(z_t, t, y).
Null conditioning (classifier-free dropout and guidance): a dropped camera zeroes the Plücker
map and sets P = I (PRoPE then reduces to 2D RoPE); dropped LiDAR zeroes every packet channel
(eq. 12's null packet). The role channel and the source latents are always kept.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import Tensor, nn

from model.adapter import ResidualAdapter, build_packet, warp_for, without_dtau
from model.camera import (
    nearest_source_views,
    plucker_rays,
    projective_matrices,
    reference_poses,
    role_map,
)
from model.transformer import PRESETS, MultiViewDiT, TransformerConfig
from schemas.errors import DataError
from schemas.modes import packet_mode

PREDICTIONS = ("x", "v")
"""Backbone output parametrizations: clean latent (x) or velocity (v, the paper's)."""
ANCHORS = ("none", "nearest_source", "reprojection")
"""What an x-prediction output is added to: nothing, or the latent of the clip's source view
whose camera centre is nearest (so an untrained net returns the copy-nearest-source view).
Measured on the science cache (docs/benchmarks_model.md) the anchor did not help, so "none"
is the default."""
T_MIN = 0.05
"""Clamp of t in the x-prediction conversion v = (z_t - z0_hat) / t."""


@dataclass(frozen=True)
class NetConfig:
    """Model sizes: latent channels C, point channels C_u, grid, image size (for K), mode."""

    c: int = 16
    c_u: int = 8
    grid_hw: tuple[int, int] = (16, 24)
    image_hw: tuple[int, int] = (224, 336)
    mode: str = "full"
    preset: str = "tiny"
    adapter_hidden: int = 256
    prope: bool = True
    patch: int | None = None  # overrides the preset's patch size (cells per token side)
    prediction: str = "x"  # what the backbone outputs: "x" (clean z_0) or "v" (the paper's)
    width: int | None = None  # overrides the preset's width
    depth: int | None = None  # overrides the preset's depth
    anchor: str = "none"  # x-prediction reads z0_hat = anchor + output (ANCHORS)
    dtau_channel: bool = True  # False: the packets' delta-tau channel is zeroed (a control)

    def to_json(self) -> dict[str, Any]:
        """JSON-compatible dict."""
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> NetConfig:
        """Inverse of `to_json`."""
        d = dict(d)
        d["grid_hw"], d["image_hw"] = tuple(d["grid_hw"]), tuple(d["image_hw"])
        d.setdefault("prediction", "v")  # checkpoints from before the option were v-prediction
        d.setdefault("width", None)
        d.setdefault("depth", None)
        d.setdefault("anchor", "none")  # checkpoints from before the option had no anchor
        return cls(**d)


@dataclass
class Condition:
    """y without z_t: c~ (B, V, C, H, W), cam (B, V, 7, H, W), P and P_inv (B, V, 4, 4);
    anchor (B, V, C, H, W) or None: what an x-prediction output is added to."""

    c_tilde: Tensor
    cam: Tensor
    P: Tensor
    P_inv: Tensor
    anchor: Tensor | None = None


class M3GDNet(nn.Module):
    """phi (adapter) and v_theta (transformer) with the camera conditioning between them."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        if cfg.preset not in PRESETS:
            raise DataError(f"unknown preset {cfg.preset!r}; one of {sorted(PRESETS)}")
        if cfg.prediction not in PREDICTIONS:
            raise DataError(f"unknown prediction {cfg.prediction!r}; one of {PREDICTIONS}")
        if cfg.anchor not in ANCHORS:
            raise DataError(f"unknown anchor {cfg.anchor!r}; one of {ANCHORS}")
        if cfg.anchor != "none" and cfg.prediction != "x":
            raise DataError(f"anchor {cfg.anchor!r} needs prediction 'x' (got {cfg.prediction!r})")
        if cfg.anchor == "reprojection" and not packet_mode(cfg.mode).warp:
            raise DataError(f"anchor 'reprojection' needs a warp packet mode (warp, full_warp), "
                            f"got {cfg.mode!r}")
        over = {"prope": cfg.prope} | {k: v for k, v in (("patch", cfg.patch),
                                                          ("width", cfg.width),
                                                          ("depth", cfg.depth)) if v is not None}
        tcfg = TransformerConfig(**{**asdict(PRESETS[cfg.preset]), **over})
        self.adapter = ResidualAdapter(cfg.c, cfg.c_u, cfg.mode, cfg.adapter_hidden,
                                       cfg.grid_hw)
        self.backbone = MultiViewDiT(cfg.c, cfg.grid_hw, tcfg)

    def condition(self, batch: dict[str, Tensor], drop_cam: Tensor,
                  drop_lidar: Tensor) -> Condition:
        """Condition from a batch (keys of `model.train_step`) with per-clip null masks (B,) bool.

        Runs the adapter exactly once. The anchor (nearest-source latents or their LiDAR
        reprojection) is kept under the null condition, like the source latents themselves.
        """
        lat, is_tgt = batch["latents"], batch["is_target"]  # (B, V, C, H, W), (B, V)
        B, V = is_tgt.shape
        warp = warp_for(self.cfg.mode, batch, self.cfg.image_hw)  # (B, V, H, W, C + 1) or None
        ell = build_packet(self.cfg.mode, batch.get("g"), batch.get("h"), self.cfg.c_u, lat,
                           self.adapter.learned, warp)
        if ell is not None and not self.cfg.dtau_channel:
            ell = without_dtau(ell)
        if ell is not None:
            ell = ell * (~drop_lidar).to(ell.dtype)[:, None, None, None, None]  # null packet
        c_tilde = self.adapter(lat, ell, is_tgt)  # (B, V, C, H, W)
        T_ref_cam = reference_poses(batch["T_world_cam"], is_tgt)  # (B, V, 4, 4) float64
        rays = plucker_rays(batch["K"], T_ref_cam, self.cfg.grid_hw, self.cfg.image_hw)
        keep = (~drop_cam).float()  # (B,)
        rays = rays * keep[:, None, None, None, None]  # (B, V, 6, H, W)
        cam = torch.cat([rays, role_map(is_tgt, self.cfg.grid_hw)], dim=2).to(lat)
        P, P_inv = projective_matrices(batch["K"], T_ref_cam, self.cfg.image_hw)  # (B, V, 4, 4)
        eye = torch.eye(4, device=P.device).expand(B, V, 4, 4)
        mask = drop_cam[:, None, None, None]
        return Condition(c_tilde, cam, torch.where(mask, eye, P), torch.where(mask, eye, P_inv),
                         self.anchor(lat, batch["T_world_cam"], is_tgt, warp))

    def forward(self, batch: dict[str, Tensor], z_t: Tensor, t: Tensor, drop_cam: Tensor,
                drop_lidar: Tensor) -> Tensor:
        """v_theta(z_t, t, y) (B, V, C, H, W) for training: the condition (with null masks
        drop_cam, drop_lidar (B,) bool) and the velocity in one call, as DistributedDataParallel
        needs (it synchronizes gradients of what `forward` ran)."""
        return self.velocity(z_t, t, self.condition(batch, drop_cam, drop_lidar))

    def anchor(self, lat: Tensor, T_world_cam: Tensor, is_tgt: Tensor,
               warp: Tensor | None = None) -> Tensor | None:
        """Per view (B, V, C, H, W): the latent of the nearest source view ('nearest_source'),
        or the LiDAR reprojection of the sources where a source filled the cell and the
        nearest source's latent elsewhere ('reprojection'; warp: the (B, V, H, W, C + 1) warp
        channels); None without anchor. Like the source latents, the anchor is kept under the
        null condition (guidance moves the residual on it, not the anchor)."""
        if self.cfg.anchor == "none":
            return None
        src = nearest_source_views(T_world_cam, is_tgt)  # (B, V)
        near = lat[torch.arange(lat.shape[0], device=lat.device)[:, None], src]
        if self.cfg.anchor == "nearest_source":
            return near
        if warp is None:
            raise DataError("anchor 'reprojection' needs the warp channels of a warp mode")
        C = lat.shape[2]
        w = warp.permute(0, 1, 4, 2, 3).to(lat.dtype)  # (B, V, C + 1, H, W)
        filled = w[:, :, C:] > 0.5  # (B, V, 1, H, W)
        return torch.where(filled, w[:, :, :C], near)

    def velocity(self, z_t: Tensor, t: Tensor, cond: Condition) -> Tensor:
        """v_theta(z_t, t, y): (B, V, C, H, W) from z_t (B, V, C, H, W) and t (B,).

        x-prediction reads the backbone output as z_0_hat and returns
        v = (z_t - z_0_hat) / max(t, T_MIN) (`x_to_velocity`), with z_0_hat = anchor + output
        when the condition has an anchor; v-prediction returns the output as is.
        """
        x = torch.cat([cond.c_tilde.to(z_t.dtype), z_t], dim=2)  # (B, V, 2C, H, W)
        out: Tensor = self.backbone(x, cond.cam, t, cond.P, cond.P_inv)
        if self.cfg.prediction == "v":
            return out
        z0_hat = out if cond.anchor is None else out + cond.anchor.to(out.dtype)
        return x_to_velocity(z_t, z0_hat, t)


def x_to_velocity(z_t: Tensor, z0_hat: Tensor, t: Tensor) -> Tensor:
    """v = (z_t - z0_hat) / max(t, T_MIN): z_t, z0_hat (B, V, C, H, W), t (B,).

    On the linear path z_t = (1 - t) z_0 + t z_1 this is exactly u = z_1 - z_0 when
    z0_hat = z_0; the clamp bounds the 1 / t gain near the data end (JiT, Li & He 2025).
    """
    tc = t.clamp_min(T_MIN).to(z_t.dtype)[:, None, None, None, None]
    return (z_t - z0_hat) / tc
