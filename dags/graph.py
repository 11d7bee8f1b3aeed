"""The m3gd stage graph: each row of the stage table (`schemas.stages`) bound to the
functions that plan and run it. Wiring only; the logic lives in pipeline/."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pipeline.analysis.geometry_check import GEOMETRY_READS, plan_geometry, run_geometry
from pipeline.run.reads import StoreReads
from pipeline.run.stage import Item, ItemResult, Stage
from pipeline.stages.clips import CLIPS_READS, plan_clips, run_clips
from pipeline.stages.encode import ENCODE_READS, encode_resources, plan_encode, run_encode
from pipeline.stages.ingest import INGEST_READS, plan_ingest, run_ingest
from pipeline.stages.packets import PACKETS_READS, plan_packets, run_packets
from pipeline.stages.select import SELECT_READS, plan_select, run_select, select_outputs
from pipeline.stages.stats import STATS_READS, plan_stats, run_stats
from pipeline.stages.synth import SYNTH_READS, plan_synth, run_synth
from schemas import stages as table
from schemas.config import M3GDConfig
from schemas.stages import StageSpec


def bind(spec: StageSpec, plan: Callable[[M3GDConfig], list[Item]],
         run: Callable[[M3GDConfig, Item], ItemResult], reads: StoreReads,
         resources: Callable[[M3GDConfig], dict[str, float]] | None = None,
         outputs: Callable[[M3GDConfig, Item], list[Path]] | None = None) -> Stage:
    """The graph node of row `spec`: its name, dependencies and unit from the table, with
    the functions that plan and run its items, what they read from the output, the worker
    resources an item needs and the table files a finished item wrote."""
    return Stage(spec.name, spec.depends, plan, run, spec.unit, reads, resources, outputs)


BINDINGS: dict[str, Stage] = {s.name: s for s in (
    bind(table.SYNTH, plan_synth, run_synth, SYNTH_READS),
    bind(table.INGEST, plan_ingest, run_ingest, INGEST_READS),
    bind(table.SELECT, plan_select, run_select, SELECT_READS, outputs=select_outputs),
    bind(table.ENCODE, plan_encode, run_encode, ENCODE_READS, encode_resources),
    bind(table.PACKETS, plan_packets, run_packets, PACKETS_READS),
    bind(table.GEOMETRY, plan_geometry, run_geometry, GEOMETRY_READS),
    bind(table.STATS, plan_stats, run_stats, STATS_READS),
    bind(table.CLIPS, plan_clips, run_clips, CLIPS_READS),
)}
"""Each stage of the table bound to its functions, by name."""

STAGES: list[Stage] = [BINDINGS[s.name] for s in table.STAGE_TABLE]
"""The stage graph, in the table's order (a row without a binding fails here, at import)."""


def stage_names() -> list[str]:
    """Names of the stages in graph order."""
    return [s.name for s in STAGES]
