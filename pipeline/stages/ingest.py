"""Ingest stage: recordings to index tables and rectified, resized images in the cache."""

from __future__ import annotations

import logging

from pipeline.ingest.sources.staging import mission_identity, staged
from pipeline.run.keys import ItemKey
from pipeline.run.reads import RECORDING_GROUPS, Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key, input_identity
from pipeline.stages.images import ImageCacheSink
from schemas.cache_layout import INGEST, GridSpec
from schemas.config import M3GDConfig
from schemas.missions import mission_of, recording_names
from store.object_store import is_url

log = logging.getLogger(__name__)

INGEST_READS = StoreReads(Reads(RECORDING_GROUPS, ("stamp_ns", "K")))
"""Its recording's group and index; rewritten arrays (images are written as whole shards)."""
def plan_ingest(cfg: M3GDConfig) -> list[Item]:
    """One item per recording, keyed by its bags' identities and the ingest config."""
    items = []
    for rec in recording_names(cfg):
        mission = mission_of(cfg, rec)
        ident = (mission_identity(mission) if is_url(mission)
                 else input_identity(mission) if mission.exists() else [])
        items.append(Item(ItemKey(rec), cache_key(INGEST, cfg.ingest, cfg.cache, ident)))
    return items


def run_ingest(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Index one recording and write its rectified images into the cache."""
    from pipeline.ingest.recording import ingest_recording

    grid = GridSpec(cfg.ingest.out_height, cfg.ingest.out_width)
    rec = item.key.require_recording()
    sink = ImageCacheSink(cfg.output_dir, rec, grid, cfg.cache.shard_views)
    with staged(mission_of(cfg, rec)) as mission:  # s3:// missions: a scratch copy
        result = ingest_recording(mission, cfg.output_dir, cfg.ingest, sink)
    counts = sink.close()
    log.info("ingest %s: input format %s", item.key, result.input_format)
    return ItemResult(done=sum(counts.values()), rejected=sum(result.rejects.values()),
                      detail={"images": counts, "rejects": result.rejects,
                              "sweeps": result.sweeps, "format": result.input_format,
                              "checks": result.checks},
                      warnings=result.warnings)


