"""Stats stage: per-recording statistics merged from the shard parts; the latent normalization."""

from __future__ import annotations

from pipeline.cache.store import open_root
from pipeline.run.keys import ItemKey
from pipeline.run.reads import ROOT_META, Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import upstream_key
from pipeline.stats.merge import merge_latent_stats, merge_recording
from schemas.config import M3GDConfig
from schemas.layout import STATS_DIRNAME
from schemas.missions import recording_names

NORM_ITEM = ItemKey.cross("latent_norm")
STATS_READS = StoreReads(Reads((f"{STATS_DIRNAME}/parts/{{r}}",)),
                         cross=Reads((ROOT_META, f"{STATS_DIRNAME}/latent_parts")))
"""A merge item reads its recording's statistics parts; the latent normalization item the
latent parts of every recording."""
def plan_stats(cfg: M3GDConfig) -> list[Item]:
    """One merge item per recording and one latent-normalization item."""
    key = upstream_key(cfg)
    return [*(Item(ItemKey(r), key) for r in recording_names(cfg)), Item(NORM_ITEM, key)]


def run_stats(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Merge one recording's shard statistics, or the latent normalization of the cache."""
    if item.key == NORM_ITEM:
        try:
            stats = merge_latent_stats(cfg.output_dir)
        except FileNotFoundError:  # merge found no statistics part (one glob, in merge)
            return ItemResult(warnings=["no view was encoded, so the cache has no latent "
                                        "normalization yet"])
        root = open_root(cfg.layout.cache)
        root.attrs["latent_norm"] = {"mean": stats.mean.tolist(), "std": stats.std.tolist(),
                                     "count": stats.count}
        # not a view: the stage's outputs count view rows only (one per view of the run)
        return ItemResult(detail={"latent_norm_cells": stats.count})
    rows = merge_recording(cfg.output_dir, item.key.require_recording())
    return ItemResult(done=rows["view_stats"], detail=rows)


