"""The m3gd stage graph: which stage feeds which. Wiring only; the logic lives in pipeline/."""

from __future__ import annotations

from pipeline.analysis.geometry_check import GEOMETRY_READS, plan_geometry, run_geometry
from pipeline.run.stage import Stage
from pipeline.stages.clips import CLIPS_READS, plan_clips, run_clips
from pipeline.stages.encode import ENCODE_READS, encode_resources, plan_encode, run_encode
from pipeline.stages.ingest import INGEST_READS, plan_ingest, run_ingest
from pipeline.stages.packets import PACKETS_READS, plan_packets, run_packets
from pipeline.stages.select import SELECT_READS, plan_select, run_select, select_outputs
from pipeline.stages.stats import STATS_READS, plan_stats, run_stats
from pipeline.stages.synth import SYNTH_READS, plan_synth, run_synth

STAGES: list[Stage] = [
    Stage("synth", (), plan_synth, run_synth, "recordings", SYNTH_READS),
    Stage("ingest", ("synth",), plan_ingest, run_ingest, "images", INGEST_READS),
    Stage("select", ("ingest",), plan_select, run_select, "views", SELECT_READS,
          outputs=select_outputs),
    Stage("encode", ("select",), plan_encode, run_encode, "views", ENCODE_READS,
          encode_resources),
    Stage("packets", ("select",), plan_packets, run_packets, "views", PACKETS_READS),
    Stage("geometry", ("packets",), plan_geometry, run_geometry, "cameras", GEOMETRY_READS),
    Stage("stats", ("encode", "packets"), plan_stats, run_stats, "rows", STATS_READS),
    Stage("clips", ("stats",), plan_clips, run_clips, "clips", CLIPS_READS),
]


def stage_names() -> list[str]:
    """Names of the stages in graph order."""
    return [s.name for s in STAGES]
