"""Sample target views, decode them with the frozen image decoder, score them beside baselines.

Latents in a batch are normalized per channel (`model.dataset`); they are mapped back with
the cached (mean, std) before decoding. Only target views are decoded and scored; the source
views generated alongside are discarded (paper, "Inference").

Every target is also scored for two trivial predictors on the same ground truth:
  copy_source  the image of the clip's source view whose camera centre is nearest the
               target's (camera distance, metres)
  mean_latent  the decoded dataset-mean latent (normalized z = 0, i.e. per-channel mean)
  reprojection every target cell with LiDAR support lifted with the target packet's depth,
               projected into the clip's source views and their latent read there
               (`model.reprojection`, nearest cell, visibility by depth order); cells that
               no source sees, or without support, take the copy_source image (the
               strongest trivial baseline in PSNR at the measured budgets); needs the
               packets' geometry g and the cameras
and, when the caller hands in the clip's reference images (`model.baselines`), the
per-pixel mean training image and the per-recording mean images. A model that does not beat
the strongest of them has learned nothing usable.

Where the reprojection can be built, every target also gets its reprojection consistency
(`model.view_consistency`): the RMS intensity difference ([0, 1] units) between a target
image and the source images read at the target's LiDAR points (16 per supported cell, each
from the source the reprojection chose for its cell); for the model's decoded sample and, at
the same points, the ground-truth image (the floor) and every baseline image
(`REPROJ_CANDIDATES`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from model.baselines import IMAGE_BASELINES, ORACLE_BASELINES
from model.camera import nearest_source_views
from model.encoders.base import ImageDecoder
from model.metrics import psnr_many, ssim_many
from model.sampler import VelocityModel, sample
from packets.reprojection import Warp, cells_to_pixels, packet_depth, warp_latents
from packets.view_consistency import image_consistency, reads
from schemas.errors import DataError

BASELINES = ("copy_source", "mean_latent", "reprojection", *IMAGE_BASELINES)
"""Trivial predictors scored beside the model on every target (the image ones when given)."""
GEOMETRIC_BASELINES = ("reprojection",)
"""Baselines that render from the cached geometry (packet depth and cameras)."""
FAIR_BASELINES = tuple(b for b in BASELINES
                       if b not in ORACLE_BASELINES and b not in GEOMETRIC_BASELINES)
"""Non-geometric baselines that see only what the model may see: the strongest of them is
the bar; the geometric ones (fair too) are reported beside it with their own margin."""
RANKED_BASELINES = tuple(b for b in BASELINES if b not in ORACLE_BASELINES)
"""The baselines "the strongest baseline" is chosen among: every one scored, geometric ones
included, except those that look at held-out views (`ORACLE_BASELINES`)."""
REPROJ_CANDIDATES = ("model", "ground_truth", "copy_source", "mean_latent", "reprojection")
"""Latents scored for reprojection consistency on every target that has a reprojection."""


@dataclass
class TargetResult:
    """One synthesized target view: its clip, view index, images, scores and baseline scores.

    baselines: name -> (PSNR dB, SSIM) of each predictor in `BASELINES` on the same target.
    reproj: name -> reprojection consistency error (RMS intensity, [0, 1]) of each of
    `REPROJ_CANDIDATES` at the same points; empty where the target has no reprojection (no
    geometry, or no LiDAR point any source sees); reproj_points: those points.
    """

    clip_id: int
    view: int
    pred: np.ndarray | None  # (h, w, 3) uint8 (None when the images were not kept)
    gt: np.ndarray | None  # (h, w, 3) uint8
    psnr: float
    ssim: float
    baselines: dict[str, tuple[float, float]] = field(default_factory=dict)
    reproj: dict[str, float] = field(default_factory=dict)
    reproj_points: int = 0


def denormalize(z: Tensor, mean: np.ndarray, std: np.ndarray) -> Tensor:
    """z * std + mean per channel: z (..., C, H, W), mean/std (C,) -> float32 (..., C, H, W)."""
    m = torch.as_tensor(mean, dtype=torch.float32)[:, None, None]
    s = torch.as_tensor(std, dtype=torch.float32)[:, None, None]
    return z.float() * s + m


SCORE_CHUNK = 8
"""Images scored at once: SSIM keeps ~25 float64 copies of each image in flight."""


def image_scores(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(PSNR dB (N,), SSIM (N,)) of uint8 image stacks (N, h, w, 3), scored on [0, 1] floats,
    `SCORE_CHUNK` images at a time (memory bounded whatever N)."""
    psnrs, ssims = [], []
    for i in range(0, len(pred), SCORE_CHUNK):
        p = torch.from_numpy(pred[i:i + SCORE_CHUNK]).permute(0, 3, 1, 2).double() / 255.0
        g = torch.from_numpy(gt[i:i + SCORE_CHUNK]).permute(0, 3, 1, 2).double() / 255.0
        psnrs.append(psnr_many(p, g).numpy())  # p, g: (n, 3, h, w)
        ssims.append(ssim_many(p, g).numpy())
    return np.concatenate(psnrs), np.concatenate(ssims)


def nearest_source(T_world_cam: Tensor, is_target: Tensor, b_idx: Tensor, v_idx: Tensor
                   ) -> Tensor:
    """Per target entry (b_idx[k], v_idx[k]), the source view of clip b with the nearest camera.

    T_world_cam (B, V, 4, 4), is_target (B, V) bool -> (M,) view indices. Raises if a clip
    with a target has no source.
    """
    try:
        return nearest_source_views(T_world_cam, is_target)[b_idx, v_idx]
    except ValueError:
        raise ValueError("copy_source baseline: a clip with a target view has no source view"
                         ) from None


def synthesize_targets(net: VelocityModel, batch: dict[str, Tensor], decoder: ImageDecoder,
                       mean: np.ndarray, std: np.ndarray, steps: int = 10,
                       guidance: float = 1.5, generator: torch.Generator | None = None,
                       tol: float | None = None, keep_images: bool = True,
                       references: list[dict[str, np.ndarray]] | None = None,
                       geometry: Tensor | None = None, temperature: float = 1.0
                       ) -> list[TargetResult]:
    """Sample a batch, decode every target view, score it and the baselines against the truth.

    batch needs 'images' (B, V, h, w, 3) uint8 (stream with `with_images=True`), and
    'T_world_cam' for the copy_source baseline (skipped without); optionally 'clip_id' (B,).
    Returns one `TargetResult` per target view, batch-major (with its images when
    `keep_images`). All M targets (and baselines) are decoded in one call and scored in one
    batched metric pass, on the CPU; the network runs where the batch's tensors are.
    references: per clip of the batch, baseline name -> image (h, w, 3) uint8
    (`model.baselines.MeanImages.references`), scored on that clip's targets.
    geometry: packet geometry g (B, V, 6, H, W) for the reprojection baseline when the batch
    has no 'g' (a mode without LiDAR input); the baseline needs 'T_world_cam' and 'K' too.
    temperature: the start noise's scale (`model.sampler.sample`; 1: the paper's sampler).
    """
    if "images" not in batch:
        raise DataError("synthesize_targets: batch has no 'images' (use with_images=True)")
    z_0 = sample(net, batch, steps, guidance, generator, tol,
                 temperature=temperature).z_0.cpu()  # (B, V, C, H, W)
    is_tgt, images = batch["is_target"].cpu(), batch["images"]
    b_idx, v_idx = torch.nonzero(is_tgt, as_tuple=True)  # target entries, batch-major
    M = int(b_idx.shape[0])
    C, H, W = z_0.shape[2:]
    lat = torch.cat([z_0[b_idx, v_idx], z_0.new_zeros(1, C, H, W)])  # (M + 1): + mean latent
    decoded = decoder.decode(denormalize(lat, mean, std).numpy())  # (M + 1, h, w, 3) uint8
    gt = images[b_idx, v_idx].numpy()  # (M, h, w, 3)
    preds = [decoded[:M], np.broadcast_to(decoded[M], gt.shape)]
    names = ["model", "mean_latent"]
    consistency: list[dict[str, float]] = [{} for _ in range(M)]
    points = [0] * M
    if "T_world_cam" in batch:
        src = nearest_source(batch["T_world_cam"].cpu(), is_tgt, b_idx, v_idx)
        copy = images[b_idx, src].numpy()
        preds.append(copy)
        names.append("copy_source")
        g = batch.get("g", geometry)
        views = (target_warps(batch, g, b_idx, v_idx, (int(gt.shape[1]), int(gt.shape[2])))
                 if g is not None and "K" in batch else None)
        rep = (reprojected_images([v.warp for v in views], mean, std, decoder, copy)
               if views else None)
        if rep is not None and views is not None:
            preds.append(rep)
            names.append("reprojection")
            cands = (decoded[:M], gt, copy, np.broadcast_to(decoded[M], gt.shape), rep)
            consistency, points = target_consistency(views, cands, images.numpy())
    p, s = image_scores(np.concatenate(preds), np.concatenate([gt] * len(preds)))
    p, s = p.reshape(len(preds), M), s.reshape(len(preds), M)
    clip_ids = batch.get("clip_id", torch.arange(is_tgt.shape[0])).cpu()
    extra = reference_scores(references, b_idx.tolist(), gt) if references else {}
    return [TargetResult(int(clip_ids[b]), v, decoded[k].copy() if keep_images else None,
                         gt[k].copy() if keep_images else None, float(p[0, k]), float(s[0, k]),
                         {**{n: (float(p[i, k]), float(s[i, k]))
                             for i, n in enumerate(names) if i}, **extra.get(k, {})},
                         consistency[k], points[k])
            for k, (b, v) in enumerate(zip(b_idx.tolist(), v_idx.tolist(), strict=True))]


@dataclass(frozen=True)
class TargetView:
    """One target's reprojection and the geometry behind it: warp (`warp_latents`, normalized
    latents), depth (H, W) m its packet depth, K (3, 3), T (4, 4) its camera, b its clip in
    the batch, src (S,) the clip's source views, K_src (S, 3, 3), T_src (S, 4, 4) theirs,
    image_hw the images' size (pixels)."""

    warp: Warp
    depth: np.ndarray
    K: np.ndarray
    T: np.ndarray
    b: int
    src: np.ndarray
    K_src: np.ndarray
    T_src: np.ndarray
    image_hw: tuple[int, int]


def target_warps(batch: dict[str, Tensor], g: Tensor, b_idx: Tensor, v_idx: Tensor,
                 image_hw: tuple[int, int]) -> list[TargetView] | None:
    """The sources' reprojection into each target (b_idx[k], v_idx[k]), in normalized latent
    units: the batch's 'latents' (B, V, C, H, W) warped by the target's packet depth (g
    (B, V, 6, H, W)) and the cameras ('K' (B, V, 3, 3), 'T_world_cam' (B, V, 4, 4); K in
    pixels of `image_hw`). None where g's grid is not the latents'."""
    lat = batch["latents"].cpu().double().numpy()  # (B, V, C, H, W)
    if tuple(g.shape[-2:]) != lat.shape[-2:]:
        return None
    depth = packet_depth(g.cpu().numpy())  # (B, V, H, W) m, 0 without support
    K = batch["K"].cpu().double().numpy()
    T = batch["T_world_cam"].cpu().double().numpy()
    is_tgt = batch["is_target"].cpu().numpy()
    out = []
    for b, v in zip(b_idx.tolist(), v_idx.tolist(), strict=True):
        src = np.flatnonzero(~is_tgt[b])
        w = warp_latents(lat[b, src], depth[b, v], K[b, v], T[b, v], K[b, src], T[b, src],
                         depth[b, src], image_hw)
        out.append(TargetView(w, depth[b, v], K[b, v], T[b, v], b, src, K[b, src], T[b, src],
                              image_hw))
    return out


def target_consistency(views: list[TargetView], candidates: tuple[np.ndarray, ...],
                       images: np.ndarray) -> tuple[list[dict[str, float]], list[int]]:
    """Per target k: the reprojection consistency error of each of `REPROJ_CANDIDATES`
    (candidates: one (M, h, w, 3) uint8 stack each, in that order) against the clip's source
    images (images (B, V, h, w, 3) uint8), empty where no point is read; and the points."""
    errors: list[dict[str, float]] = []
    points: list[int] = []
    for k, view in enumerate(views):
        at = reads(view.depth, view.K, view.T, view.K_src, view.T_src, view.warp.source,
                   view.image_hw)
        c = image_consistency(np.stack([cand[k] for cand in candidates]),
                              images[view.b, view.src], at)
        errors.append({} if c is None else dict(zip(REPROJ_CANDIDATES, c.errors.tolist(),
                                                    strict=True)))
        points.append(0 if c is None else c.points)
    return errors, points


def reprojected_images(warps: list[Warp], mean: np.ndarray, std: np.ndarray,
                       decoder: ImageDecoder, fallback: np.ndarray) -> np.ndarray | None:
    """The reprojection baseline's image (M, h, w, 3) uint8 of each target.

    The targets' reprojections (`target_warps`, normalized latents) are mapped back with
    mean/std (C,), decoded, and pasted over `fallback` (M, h, w, 3) uint8 on the cells some
    source filled. None (baseline left out) where the decoded size is not the images'.
    """
    hw = (int(fallback.shape[1]), int(fallback.shape[2]))
    valid = np.stack([w.valid for w in warps])  # (M, H, W)
    z = torch.from_numpy(np.stack([w.latent for w in warps]).astype(np.float32))
    lat = np.where(valid[:, None], denormalize(z, mean, std).numpy(), np.float32(0.0))
    decoded = decoder.decode(lat)  # (M, h, w, 3)
    if decoded.shape != fallback.shape:
        return None
    masks = np.stack([cells_to_pixels(m, hw) for m in valid])
    out: np.ndarray = np.where(masks[..., None], decoded, fallback)
    return out


def reference_scores(references: list[dict[str, np.ndarray]], clip_of: list[int],
                     gt: np.ndarray) -> dict[int, dict[str, tuple[float, float]]]:
    """Per target k (clip clip_of[k], truth gt[k] (h, w, 3) uint8): (PSNR, SSIM) of every
    reference image its clip has; one batched metric pass per baseline name."""
    out: dict[int, dict[str, tuple[float, float]]] = {}
    for name in IMAGE_BASELINES:
        ks = [k for k, b in enumerate(clip_of) if name in references[b]]
        if not ks:
            continue
        p, s = image_scores(np.stack([references[clip_of[k]][name] for k in ks]), gt[ks])
        for j, k in enumerate(ks):
            out.setdefault(k, {})[name] = (float(p[j]), float(s[j]))
    return out
