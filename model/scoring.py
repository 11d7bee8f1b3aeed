"""The one scoring loop: sample, decode and score eval-split targets beside the baselines.

Shared by `m3gd sample`, `m3gd eval`, `m3gd bench sampler`, `m3gd bench science` and
`model.compare.train_and_score` (file output lives in `pipeline.analysis.model_eval`). The image
decoder is rebuilt from the encoder identity stored in the cache group attributes; only
`patch` has one (exact for C >= 588, least-squares below). Scores are PSNR (dB) and SSIM of
decoded target views against the cached ground-truth images of the 'eval' split, with the
baselines of `model.evaluate` on the same targets.
"""

from __future__ import annotations

import logging
import statistics
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from model.baselines import MeanImages, mean_images_for
from model.checkpoint import load_checkpoint, prefixed
from model.dataset import NEEDS, ClipStream, make_loader, take_clips
from model.device import to_device
from model.encoders.base import ImageDecoder
from model.encoders.patch import PatchEncoder
from model.evaluate import (
    BASELINES,
    FAIR_BASELINES,
    RANKED_BASELINES,
    REPROJ_CANDIDATES,
    TargetResult,
    synthesize_targets,
)
from model.loop import model_batch
from model.net import M3GDNet, NetConfig
from model.validation import t_binned_loss
from schemas.cache_layout import group_name, stored_arrays
from schemas.layout import OutputLayout
from store.cache_io import read_clip

log = logging.getLogger(__name__)


def check_cache(output_dir: Path) -> None:
    """Refuse an output directory without a cache or clip index, naming what is missing."""
    layout = OutputLayout(output_dir)
    for what in (layout.cache, layout.clips):
        if not what.exists():
            raise FileNotFoundError(f"{what} does not exist; run `m3gd run` first to build the "
                                    "cache and the clip index")


def check_mode(stream: ClipStream) -> None:
    """Refuse a packet mode whose arrays (g, h) the cache does not hold."""
    where, _ = stream.first_group()
    missing = [n for n in NEEDS[stream.mode]
               if not all((where / a / "zarr.json").exists() for a in stored_arrays(n))]
    if missing:
        raise ValueError(f"mode {stream.mode!r} needs {', '.join(missing)}, which {where} "
                         "does not hold (cache built with another packets.mode)")


def image_decoder(stream: ClipStream, seed: int) -> ImageDecoder:
    """The decoder of the image encoder named in the cache group attributes.

    `seed`: the configured encoders.seed; the rebuilt encoder's weights hash must match the
    cached one, so a decoder never silently differs from the encoder that wrote the latents.
    """
    where, attrs = stream.first_group()
    ident = attrs.image_encoder
    if ident is None:
        raise ValueError(f"{where}: no image encoder identity in the group attributes")
    if ident.name != "patch":
        raise ValueError(f"image encoder {ident.name!r} (in {where}) has no decoder; sample and "
                         "eval decode target latents and need an encoder with one "
                         "(encoders.image: patch)")
    dec = PatchEncoder(ident.channels, seed)
    if dec.weights_hash != ident.weights_hash:
        raise ValueError(f"{where}: cached patch encoder hash {ident.weights_hash} differs from "
                         f"PatchEncoder(C={ident.channels}, seed={seed}) "
                         f"({dec.weights_hash}); set encoders.seed to the seed of the cache")
    if not dec.invertible:
        log.warning("patch encoder with C = %d < 588: decoding is a least-squares "
                    "projection, so even a perfect latent decodes with a loss", ident.channels)
    return dec


def load_net(checkpoint: Path, ema: bool, device: torch.device | None = None
             ) -> tuple[M3GDNet, dict[str, Any]]:
    """(network in eval mode on `device`, checkpoint state) of a checkpoint; EMA weights if
    `ema` else raw. Only that one network is built (no optimizer, no second copy)."""
    tensors, meta = load_checkpoint(checkpoint)
    net = M3GDNet(NetConfig.from_json(meta["net"]))
    net.load_state_dict(prefixed(tensors, "ema" if ema else "model"))
    del tensors
    return net.to(device or torch.device("cpu")).eval().requires_grad_(False), meta


def _take(batch: dict[str, Tensor], n: int) -> dict[str, Tensor]:
    """The first `n` clips of a batch (packed h cut at those clips' rows)."""
    return take_clips(batch, n)


def eval_batches(stream: ClipStream, batch_size: int, clips: int | None
                 ) -> Iterator[dict[str, Tensor]]:
    """Batches of the first `clips` clips of `stream` (all when None), last one cut."""
    seen = 0
    for batch in make_loader(stream, batch_size):
        n = int(batch["clip_id"].shape[0])
        if clips is not None and seen + n > clips:
            batch, n = _take(batch, clips - seen), clips - seen
        if n:
            yield batch
        seen += n
        if clips is not None and seen >= clips:
            return


def score_clips(net: M3GDNet, stream: ClipStream, decoder: ImageDecoder, clips: int | None,
                batch_size: int, steps: int, guidance: float, tol: float | None, seed: int,
                on_batch: Callable[[int], None] | None = None, keep_images: bool = True,
                image_baselines: bool = True, train_recordings: set[str] | None = None,
                temperature: float = 1.0) -> list[TargetResult]:
    """Sample, decode and score every target view of the first `clips` clips of `stream`.

    image_baselines: also score the mean training image and the recording means
    (`model.baselines`) over the training views of `train_recordings` (None: all).

    `stream` must have with_images=True and shuffle=False; the noise is seeded by `seed` and
    scaled by `temperature` (`model.sampler.sample`).
    Streams in batches of `batch_size` clips under inference mode, on the network's device;
    each batch is decoded, scored and freed before the next is read (only the scores, and
    the images when `keep_images`, are kept). on_batch(n_clips) is called after each batch.
    """
    gen = torch.Generator().manual_seed(seed)
    device = next(iter(net.parameters())).device if isinstance(net, torch.nn.Module) else None
    means = mean_images(stream, train_recordings) if image_baselines else None
    results: list[TargetResult] = []
    with torch.inference_mode():
        for batch in eval_batches(stream, batch_size, clips):
            keep = {**model_batch(batch), "clip_id": batch["clip_id"]}
            if device is not None:
                keep = to_device(keep, device)
            keep["images"] = batch["images"]  # decoded and scored on the CPU
            refs = None if means is None else clip_references(means, stream, batch)
            geometry = None if "g" in batch else clip_geometry(stream, batch)
            results += synthesize_targets(net, keep, decoder, stream.mean, stream.std, steps,
                                          guidance, gen, tol, keep_images, refs, geometry,
                                          temperature)
            if on_batch is not None:
                on_batch(int(batch["clip_id"].shape[0]))
            del batch, keep
    return results


def mean_images(stream: ClipStream, train_recordings: set[str] | None
                ) -> MeanImages | None:
    """The mean-image baselines of a local stream's cache (None on object storage or
    without training views, with a warning: the other baselines still stand)."""
    if stream.remote is not None:
        log.warning("mean-image baselines are not computed for a cache on object storage")
        return None
    try:
        return mean_images_for(stream.cache.parent, stream.clips, train_recordings)
    except (ValueError, FileNotFoundError) as err:
        log.warning("no mean-image baselines: %s", err)
        return None


def clip_references(means: MeanImages, stream: ClipStream, batch: dict[str, Tensor]
                    ) -> list[dict[str, np.ndarray]]:
    """Per clip of a loader batch (with images), its mean-image baseline images."""
    rows = {int(c["clip_id"]): c for c in stream.clips}
    images = batch["images"].numpy()  # (B, V, h, w, 3) uint8
    return [means.references(rows[int(cid)], images[b])
            for b, cid in enumerate(batch["clip_id"].tolist())]


def clip_geometry(stream: ClipStream, batch: dict[str, Tensor]) -> Tensor | None:
    """Packet geometry g (B, V, 6, H, W) float32 of a batch's clips read from a local cache
    for the reprojection baseline of a mode that does not stream g (None on object
    storage or for a cache without g: the baseline is then left out)."""
    if stream.remote is not None:
        return None
    rows = {int(c["clip_id"]): c for c in stream.clips}
    out = []
    for cid in batch["clip_id"].tolist():
        clip = rows[int(cid)]
        group = stream.cache / group_name(clip["recording"], clip["camera"])
        if not (group / "g" / "zarr.json").exists():
            return None
        out.append(read_clip(group, ["g"], list(clip["frames"]), stream.reader)["g"])
    return torch.from_numpy(np.stack(out)).float()


def held_out_scores(net: M3GDNet, stream: ClipStream, decoder: ImageDecoder | None,
                    clips: int, batch_size: int, steps: int, guidance: float, seed: int
                    ) -> dict[str, Any]:
    """What a training log records at intervals on the first `clips` eval clips: the
    t-binned validation loss (fixed noise) and, with a decoder, the model's and the
    baselines' mean PSNR (dB). `net` is left in the mode it came in."""
    was_training = net.training
    net.eval()
    device = next(iter(net.parameters())).device
    try:
        with torch.inference_mode():
            val = t_binned_loss(net, (to_device(model_batch(b), device)
                                      for b in eval_batches(stream, batch_size, clips)), seed=seed)
        out: dict[str, Any] = {"val_loss_t": val["loss"], "val_loss_mean": val["mean"]}
        if decoder is not None:
            res = score_clips(net, stream, decoder, clips, batch_size, steps, guidance, None,
                              seed, keep_images=False)
            summary = summarize(res, stream)
            out |= {"psnr_model": summary["psnr_mean"], "eval_clips": summary["clips"],
                    **{f"psnr_{n}": v["psnr_mean"]
                       for n, v in summary.get("baselines", {}).items()}}
    finally:
        net.train(was_training)
    return out


def _means(results: list[TargetResult]) -> dict[str, Any]:
    """Targets, mean and median PSNR (dB), mean SSIM of `results` (non-empty); the baselines'
    means on the same targets (those every target has) and the model's margins over the
    strongest fair non-geometric baseline (`FAIR_BASELINES`): in PSNR (dB) and in SSIM, each
    against the baseline strongest in that metric; and its PSNR margin over the reprojection
    baseline (`margin_reprojection_db`) where every target has it; the strongest of every
    baseline scored (`RANKED_BASELINES`: `strongest_baseline`, `margin_strongest_db`, and by
    SSIM `strongest_baseline_by_ssim`, `ssim_margin_strongest`); the reprojection
    consistency (`reproj_means`) where any target has it."""
    psnrs = [r.psnr for r in results]
    out: dict[str, Any] = {"targets": len(results), "psnr_mean": statistics.fmean(psnrs),
                           "psnr_median": statistics.median(psnrs),
                           "ssim_mean": statistics.fmean(r.ssim for r in results)}
    base = {n: {"psnr_mean": statistics.fmean(r.baselines[n][0] for r in results),
                "ssim_mean": statistics.fmean(r.baselines[n][1] for r in results)}
            for n in BASELINES if all(n in r.baselines for r in results)}
    fair = [n for n in base if n in FAIR_BASELINES]
    if fair:
        best = max(fair, key=lambda n: base[n]["psnr_mean"])
        best_ssim = max(fair, key=lambda n: base[n]["ssim_mean"])
        out |= {"baselines": base, "better_baseline": best,
                "margin_db": out["psnr_mean"] - base[best]["psnr_mean"],
                "strongest_ssim_baseline": best_ssim,
                "ssim_margin": out["ssim_mean"] - base[best_ssim]["ssim_mean"]}
    if "reprojection" in base:
        out["margin_reprojection_db"] = out["psnr_mean"] - base["reprojection"]["psnr_mean"]
    ranked = [n for n in base if n in RANKED_BASELINES]
    if ranked:  # the strongest of every baseline scored (the LiDAR reprojection included)
        top = max(ranked, key=lambda n: base[n]["psnr_mean"])
        top_ssim = max(ranked, key=lambda n: base[n]["ssim_mean"])
        out |= {"strongest_baseline": top,
                "margin_strongest_db": out["psnr_mean"] - base[top]["psnr_mean"],
                "strongest_baseline_by_ssim": top_ssim,
                "ssim_margin_strongest": out["ssim_mean"] - base[top_ssim]["ssim_mean"]}
    return out | reproj_means(results)


def reproj_means(results: list[TargetResult]) -> dict[str, Any]:
    """The reprojection consistency over the targets that have it (`model.evaluate`):
    reproj_err (the model's mean, RMS intensity in [0, 1]), reproj_err_baselines (name ->
    mean of the ground truth, the floor, and the baselines, on the same targets and points),
    reproj_targets and reproj_points_mean (points per target); {} when none."""
    scored = [r for r in results if r.reproj]
    if not scored:
        return {}
    return {"reproj_err": statistics.fmean(r.reproj["model"] for r in scored),
            "reproj_err_baselines": {n: statistics.fmean(r.reproj[n] for r in scored)
                                     for n in REPROJ_CANDIDATES if n != "model"},
            "reproj_targets": len(scored),
            "reproj_points_mean": statistics.fmean(r.reproj_points for r in scored)}


def summarize(results: list[TargetResult], stream: ClipStream) -> dict[str, Any]:
    """Mean scores over all targets, and over the hard and other clips when any is hard."""
    if not results:
        raise ValueError(f"{stream.cache}: no eval clip with a target view was scored")
    hard = {int(c["clip_id"]): bool(c["hard"]) for c in stream.clips}
    out: dict[str, Any] = {"clips": len({r.clip_id for r in results}), **_means(results)}
    in_hard = [r for r in results if hard.get(r.clip_id, False)]
    if in_hard:
        out["hard"] = _means(in_hard)
        rest = [r for r in results if not hard.get(r.clip_id, False)]
        if rest:
            out["not_hard"] = _means(rest)
    return out


def target_rows(results: list[TargetResult], stream: ClipStream) -> list[dict[str, Any]]:
    """One row per scored target: clip, view, hard flag, PSNR, SSIM, the baselines' PSNR and
    SSIM, and the reprojection consistency of every candidate (reproj_err for the model,
    reproj_err_<name> for the others; null where the target has none) with its points."""
    hard = {int(c["clip_id"]): bool(c["hard"]) for c in stream.clips}
    return [{"clip_id": r.clip_id, "view": r.view, "hard": hard.get(r.clip_id, False),
             "psnr": r.psnr, "ssim": r.ssim,
             **{f"{k}_{n}": r.baselines[n][i] for n in BASELINES if n in r.baselines
                for i, k in enumerate(("psnr", "ssim"))},
             **{"reproj_err" if n == "model" else f"reproj_err_{n}": r.reproj.get(n)
                for n in REPROJ_CANDIDATES}, "reproj_points": r.reproj_points}
            for r in results]
