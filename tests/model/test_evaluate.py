"""Synthesis + decoding + scoring with the exact patch decoder and oracle/zero velocity fields."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from model.encoders.patch import PatchEncoder
from model.evaluate import (
    REPROJ_CANDIDATES,
    denormalize,
    reprojected_images,
    synthesize_targets,
    target_warps,
)
from model.net import Condition

C = 588  # the patch map is exactly invertible from 588 channels


class OracleField:
    """v = (z_t - z_0) / t towards known clean latents z_0: Euler lands on z_0 exactly."""

    def __init__(self, z_0: Tensor | None) -> None:
        self.z_0 = z_0

    def condition(self, batch: dict[str, Tensor], drop_cam: Tensor, drop_lidar: Tensor
                  ) -> Condition:
        e = torch.zeros(drop_cam.shape[0])
        return Condition(e, e, e, e)

    def velocity(self, z_t: Tensor, t: Tensor, cond: Condition) -> Tensor:
        if self.z_0 is None:
            return torch.zeros_like(z_t)
        z_0 = self.z_0.repeat(z_t.shape[0] // self.z_0.shape[0], 1, 1, 1, 1)
        return (z_t - z_0) / t[:, None, None, None, None]


def _batch() -> tuple[dict[str, Tensor], np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    enc = PatchEncoder(C)
    images = rng.integers(0, 256, (2, 3, 14, 28, 3), dtype=np.uint8)  # (B, V, h, w, 3)
    lat = enc.encode(images.reshape(6, 14, 28, 3))[0].reshape(2, 3, C, 1, 2)
    mean, std = lat.mean(axis=(0, 1, 3, 4)), lat.std(axis=(0, 1, 3, 4)) + 1e-3
    z = (lat - mean[:, None, None]) / std[:, None, None]
    is_tgt = torch.tensor([[False, True, True], [False, False, True]])
    batch = {"latents": torch.from_numpy(z).float(), "images": torch.from_numpy(images),
             "is_target": is_tgt, "clip_id": torch.tensor([7, 9])}
    return batch, mean, std


def test_oracle_field_reproduces_targets_exactly() -> None:
    batch, mean, std = _batch()
    res = synthesize_targets(OracleField(batch["latents"]), batch, PatchEncoder(C), mean, std,
                             steps=4, generator=torch.Generator().manual_seed(0))
    assert [(r.clip_id, r.view) for r in res] == [(7, 1), (7, 2), (9, 2)]
    for r in res:
        assert np.array_equal(r.pred, r.gt) and r.psnr == math.inf
        assert abs(r.ssim - 1.0) < 1e-12


def test_noise_field_scores_poorly() -> None:
    batch, mean, std = _batch()
    res = synthesize_targets(OracleField(None), batch, PatchEncoder(C), mean, std, steps=2,
                             generator=torch.Generator().manual_seed(0))
    assert all(r.psnr < 15.0 and r.ssim < 0.5 for r in res)


def test_denormalize_inverts_normalization() -> None:
    _, mean, std = _batch()
    z = torch.randn(2, C, 1, 2)
    back = (denormalize(z, mean, std) - torch.from_numpy(mean).float()[:, None, None])
    assert torch.allclose(back / torch.from_numpy(std).float()[:, None, None], z, atol=1e-4)


def _two_cell_scene() -> tuple[dict[str, Tensor], np.ndarray, np.ndarray, PatchEncoder,
                                tuple[np.ndarray, ...]]:
    """Target [A | B], source [B | C] seen from one cell width to the right on a
    fronto-parallel plane (the target's cell 1 is the source's cell 0)."""
    rng = np.random.default_rng(1)
    enc = PatchEncoder(C)
    A, B_, Cc = (rng.integers(0, 256, (14, 14, 3), dtype=np.uint8) for _ in range(3))
    images = np.stack([np.concatenate([B_, Cc], 1), np.concatenate([A, B_], 1)])[None]
    lat = enc.encode(images.reshape(2, 14, 28, 3))[0].reshape(1, 2, C, 1, 2)
    mean, std = lat.mean(axis=(0, 1, 3, 4)), lat.std(axis=(0, 1, 3, 4)) + 1e-3
    Z, f = 4.0, 20.0
    K = np.array([[f, 0, 13.5], [0, f, 6.5], [0, 0, 1]])
    T_src = np.eye(4)
    T_src[0, 3] = 14 * Z / f
    g = np.zeros((1, 2, 6, 1, 2), np.float32)
    g[:, :, 0], g[:, :, 2] = 1.0, 1.0 / Z
    batch = {"latents": torch.from_numpy((lat - mean[:, None, None]) / std[:, None, None]),
             "images": torch.from_numpy(images), "is_target": torch.tensor([[False, True]]),
             "K": torch.from_numpy(np.stack([K, K])[None]).float(),
             "T_world_cam": torch.from_numpy(np.stack([T_src, np.eye(4)])[None]),
             "g": torch.from_numpy(g)}
    return batch, mean, std, enc, (images, A, B_, Cc)


def test_reprojection_baseline_renders_the_seen_cell_and_falls_back_elsewhere() -> None:
    """The reprojection paints B exactly where the target shows B and keeps the copy-source
    image on the cell no source sees."""
    batch, mean, std, enc, (images, _A, B_, _C) = _two_cell_scene()
    fallback = images[:, 0]
    warps = target_warps(batch, batch["g"], torch.tensor([0]), torch.tensor([1]), (14, 28))
    assert warps is not None
    out = reprojected_images([v.warp for v in warps], mean, std, enc, fallback)
    assert np.array_equal(out[0, :, 14:], B_) and np.array_equal(out[0, :, :14], B_)
    res = synthesize_targets(OracleField(None), batch, enc, mean, std, steps=1,
                             generator=torch.Generator().manual_seed(0))
    assert res[0].baselines["reprojection"][0] > res[0].baselines["copy_source"][0]
    no_geometry = {k: v for k, v in batch.items() if k != "g"}
    res = synthesize_targets(OracleField(None), no_geometry, enc, mean, std, steps=1,
                             generator=torch.Generator().manual_seed(0))
    assert "reprojection" not in res[0].baselines


def test_reprojection_consistency_of_truth_model_and_baselines() -> None:
    """At the 16 points of the one seen cell (target cell 1 = source cell 0 = B) the ground
    truth equals the source read there (0), an oracle model and the reprojection baseline
    too; copying the source (C there), the mean latent and a noise model do not."""
    batch, mean, std, enc, _ = _two_cell_scene()
    res = synthesize_targets(OracleField(batch["latents"]), batch, enc, mean, std, steps=2,
                             generator=torch.Generator().manual_seed(0))
    r = res[0].reproj
    assert set(r) == set(REPROJ_CANDIDATES) and res[0].reproj_points == 16
    assert max(r["ground_truth"], r["model"], r["reprojection"]) < 1e-12
    assert r["copy_source"] > 0.1 and r["mean_latent"] > 0.1
    noise = synthesize_targets(OracleField(None), batch, enc, mean, std, steps=1,
                               generator=torch.Generator().manual_seed(0))[0].reproj
    assert noise["model"] > 0.1 and noise["ground_truth"] < 1e-12


def test_no_reprojection_no_consistency_score() -> None:
    batch, mean, std, enc, _ = _two_cell_scene()
    unsupported = {**batch, "g": torch.zeros_like(batch["g"])}
    for b in (unsupported, {k: v for k, v in batch.items() if k != "g"}):
        res = synthesize_targets(OracleField(None), b, enc, mean, std, steps=1,
                                 generator=torch.Generator().manual_seed(0))
        assert res[0].reproj == {} and res[0].reproj_points == 0
