"""Encode stage: the frozen image encoder once per valid view, latents into the cache.

Items are (recording, camera, shard). A shard whose done-mark carries the item's
cache key is skipped, so reruns never re-encode. Latents are stored as float16
by default: values beyond float16 range are clipped and counted (never Inf).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from packets.running_stats import ChannelStats
from pipeline.run.keys import ItemKey
from pipeline.run.reads import ROOT_META, Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key, image_encoder, run_groups
from pipeline.stats.merge import LatentPart, latent_part_path, write_latent_part
from schemas.cache_layout import (
    ENCODE,
    F16_MAX,
    EncoderIdentity,
    GridSpec,
    GroupAttrs,
    group_name,
    latent_array,
    shard_regions,
)
from schemas.config import M3GDConfig
from schemas.errors import DataError
from schemas.layout import CACHE_DIRNAME, DONE_DIRNAME
from store.cache_io import read_views
from store.cache_store import (
    array_dir,
    ensure_array,
    mark_shard_done,
    open_root,
    set_group_attrs,
    shard_done,
    shard_slice,
    write_region,
)
from store.shard_writer import ShardWriter

BATCH = 8

ENCODE_READS = StoreReads(
    Reads((ROOT_META, f"{CACHE_DIRNAME}/{{r}}/zarr.json", f"{CACHE_DIRNAME}/{{r}}/{{c}}",
           f"{DONE_DIRNAME}/{{r}}/{{c}}"), ("images", "valid")),
    plan=(CACHE_DIRNAME,))
"""Its shard of images and valid flags (latents are written as whole shards); the plan reads
the cache metadata."""


def plan_encode(cfg: M3GDConfig) -> list[Item]:
    """One item per shard of every recording-camera group."""
    items = []
    for rec, cam, attrs in run_groups(cfg):
        key = cache_key(ENCODE, cfg.encoders, cfg.cache, cfg.ingest, cfg.select,
                        rec, cam, attrs.n_views)
        for shard, _ in enumerate(shard_regions(attrs.n_views, attrs.shard_views)):
            items.append(Item(ItemKey(rec, cam, shard), key))
    return items


def encode_resources(cfg: M3GDConfig) -> dict[str, float]:
    """Dask resources an encode item needs (encoders.worker_resources, e.g. GPU=1)."""
    return cfg.encoders.resources


def to_storage(latents: np.ndarray, dtype: str) -> tuple[np.ndarray, int]:
    """Cast float32 latents to the storage dtype; clip float16 overflow and count it."""
    if dtype == "float32":
        return latents.astype(np.float32), 0
    over = int(np.count_nonzero(np.abs(latents) > F16_MAX))
    return np.clip(latents, -F16_MAX, F16_MAX).astype(np.float16), over


def encode_images(enc: Any, images: np.ndarray) -> np.ndarray:
    """Level-0 latents (B, C, H, W) float32 of uint8 images (B, H, W, 3), in small batches."""
    outs = []
    for start in range(0, len(images), BATCH):
        levels = enc.encode(images[start:start + BATCH])
        outs.append(levels[0])
    return np.concatenate(outs)


def run_encode(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Encode the valid views of one shard and write their latents and statistics."""
    rec, cam, shard = item.key.require_recording(), item.key.camera, item.key.shard
    if cam is None or shard is None:
        raise DataError(f"encode item {item.key} names no camera shard")
    group = open_root(cfg.layout.cache)[group_name(rec, cam)]
    assert isinstance(group, zarr.Group)
    attrs = GroupAttrs.from_attrs(dict(group.attrs), group_name(rec, cam))
    if shard_done(group, ENCODE, shard, item.cache_key):
        return ItemResult(detail={"skipped_shard": True})
    enc = image_encoder(cfg.encoders)
    region = shard_slice(shard, attrs.n_views, attrs.shard_views)
    frames = list(range(region.start, region.stop))
    images = read_views(_path(group, "images"), frames)
    valid = read_views(_path(group, "valid"), frames).astype(bool)
    grid = GridSpec(attrs.image_h, attrs.image_w, attrs.patch)
    spec = latent_array(grid, int(enc.out_channels), cfg.cache.latent_dtype)
    out = np.zeros((len(frames), *spec.view_shape), np.float32)
    if valid.any():
        out[valid] = encode_images(enc, images[valid])
    stored, overflow = to_storage(out, cfg.cache.latent_dtype)
    with ShardWriter() as writer:  # the shard file is written while the statistics run
        latents = ensure_array(group, spec, attrs.n_views, attrs.shard_views, replace=True)
        write_region(latents, region.start, stored, writer)
        cells = stored[valid].astype(np.float64).transpose(0, 2, 3, 1).reshape(
            -1, spec.view_shape[0])
        part = LatentPart(group_name(rec, cam), shard, (region.start, region.stop),
                          int(valid.sum()), item.cache_key)
        write_latent_part(latent_part_path(cfg.output_dir, rec, cam, shard),
                          ChannelStats.of(cells), part)
    _set_identity(group, attrs, enc.identity())
    mark_shard_done(group, ENCODE, shard, item.cache_key)
    # views select rejected are skipped, not refused again: select's summary row counts them
    return ItemResult(done=int(valid.sum()),
                      detail={"float16_overflow": overflow, "encoder_calls": int(valid.sum()),
                              "skipped_invalid": int((~valid).sum())})


def _path(group: zarr.Group, name: str) -> Path:
    """Directory of array `name` in `group`."""
    arr = group[name]
    assert isinstance(arr, zarr.Array)
    return array_dir(arr)


def _set_identity(group: zarr.Group, attrs: GroupAttrs, ident: EncoderIdentity) -> None:
    """Record the image encoder identity in the group attributes (idempotent)."""
    if attrs.image_encoder != ident:
        set_group_attrs(group, dataclasses.replace(attrs, image_encoder=ident).to_attrs())
