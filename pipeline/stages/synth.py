"""Synth stage: synthetic GrandTour-format recordings when none is configured."""

from __future__ import annotations

from pipeline.run.keys import ItemKey
from pipeline.run.reads import Reads, StoreReads
from pipeline.run.stage import Item, ItemResult
from pipeline.stages.common import cache_key
from schemas.config import M3GDConfig
from schemas.missions import synth_mission_name, synth_scene_of
from schemas.stages import SYNTH

SYNTH_READS = StoreReads(Reads(()))
"""A synth item reads nothing from the output."""
def plan_synth(cfg: M3GDConfig) -> list[Item]:
    """One item per scene, only when no real recording is configured."""
    if cfg.ingest.recordings:
        return []
    return [Item(ItemKey(synth_mission_name(s, cfg.synth.seed)),
                 cache_key(SYNTH.name, cfg.synth, s)) for s in cfg.synth.scenes]


def run_synth(cfg: M3GDConfig, item: Item) -> ItemResult:
    """Generate one synthetic recording."""
    from pipeline.synth.api import synthesize

    mission = item.key.require_recording()
    result = synthesize(cfg.layout.recordings, cfg.synth, synth_scene_of(cfg, mission),
                        mission=mission)
    return ItemResult(done=1, detail={"result": str(result)})


