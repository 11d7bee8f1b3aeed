"""Stats stage: per-recording statistics merged from the shard parts; the latent normalization."""

from __future__ import annotations

import logging

import numpy as np

from pipeline.cache.verify import done_key, drop_marks_past
from pipeline.run.checksums import NORM_ATTR
from pipeline.run.keys import ItemKey
from pipeline.run.reads import ROOT_META, Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import run_groups, upstream_key
from pipeline.stats.merge import LatentPart, merge_latent_parts, merge_recording
from schemas.cache_layout import ENCODE, LatentNorm, group_name, shard_regions
from schemas.config import M3GDConfig
from schemas.errors import MissingInputError
from schemas.layout import CACHE_DIRNAME, DONE_DIRNAME, STATS_DIRNAME
from schemas.missions import recording_names
from schemas.tables import STATS_LAYOUT_VERSION
from store.cache_io import read_views
from store.cache_store import open_root, set_group_attrs

log = logging.getLogger(__name__)

NORM_ITEM = ItemKey.cross(NORM_ATTR)
STATS_READS = StoreReads(Reads((f"{STATS_DIRNAME}/parts/{{r}}", f"{CACHE_DIRNAME}/{{r}}",
                                f"{DONE_DIRNAME}/{{r}}")),
                         cross=Reads((ROOT_META, f"{STATS_DIRNAME}/latent_parts",
                                      CACHE_DIRNAME, DONE_DIRNAME), ("valid",)))
"""A merge item reads its recording's statistics parts, cache metadata (its shards) and
done-marks (those past the last shard are removed: on the store too); the
latent normalization item the latent parts of every recording, the valid flags and the
encode done-marks they are checked against."""


def plan_stats(cfg: M3GDConfig) -> list[Item]:
    """One merge item per recording and one latent-normalization item. A merge item's key
    names the table layout it writes, so an output of an earlier layout is merged again."""
    key = upstream_key(cfg)
    merge_key = f"{key}-layout{STATS_LAYOUT_VERSION}"
    return [*(Item(ItemKey(r), merge_key) for r in recording_names(cfg)), Item(NORM_ITEM, key)]


def run_stats(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Merge one recording's shard statistics, or the latent normalization of the cache;
    each from exactly the shards the cache holds now (parts of other shards removed)."""
    if item.key == NORM_ITEM:
        return _latent_norm(cfg)
    rec = item.key.require_recording()
    shards = {cam: len(shard_regions(a.n_views, a.shard_views))
              for r, cam, a in run_groups(cfg) if r == rec}
    for cam, n in shards.items():  # marks of shards an earlier layout had past the last
        drop_marks_past(cfg.layout.cache, group_name(rec, cam), n)
    rows = merge_recording(cfg.output_dir, rec, shards)
    return ItemResult(done=rows["view_stats"], detail=rows)


def expected_latent_parts(cfg: M3GDConfig) -> list[LatentPart]:
    """The latent statistics parts the cache's shards call for now: each shard's views, its
    valid views (the cache's `valid`) and its encode done-mark's key."""
    cache = cfg.layout.cache
    parts = []
    for rec, cam, attrs in run_groups(cfg):
        group = group_name(rec, cam)
        valid = read_views(cache / group / "valid", list(range(attrs.n_views))).astype(bool)
        for shard, (start, stop) in enumerate(shard_regions(attrs.n_views, attrs.shard_views)):
            key = done_key(cache, group, ENCODE, shard)
            if key is None:
                raise MissingInputError(f"{cache / group}: shard {shard} is not encoded; run "
                                        "m3gd run again")
            parts.append(LatentPart(group, shard, (start, stop),
                                    int(np.count_nonzero(valid[start:stop])), key))
    return parts


def _latent_norm(cfg: M3GDConfig) -> ItemResult:
    """Merge the latent statistics of the cache's shards into the root's `latent_norm`."""
    parts = expected_latent_parts(cfg)
    if not any(p.valid_views for p in parts):
        return ItemResult(warnings=["no view was encoded, so the cache has no latent "
                                    "normalization yet"])
    stats, groups, removed = merge_latent_parts(cfg.output_dir, parts)
    if removed:
        log.info("latent statistics of %d shard(s) the cache no longer holds removed (%s)",
                 len(removed), removed[0])
    norm = LatentNorm(stats.mean.tolist(), stats.std.tolist(), stats.count, groups)
    # through the guarded writer: the root's `zarr.json` gets its checksum sidecar
    set_group_attrs(open_root(cfg.layout.cache), {NORM_ATTR: norm.to_attrs()})
    # not a view: the stage's outputs count view rows only (one per view of the run)
    return ItemResult(detail={"latent_norm_cells": stats.count, "latent_norm_views": norm.views})
