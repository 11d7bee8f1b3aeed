"""The m3gd stage graph: which stage feeds which. Wiring only; the logic lives in pipeline/."""

from __future__ import annotations

from pipeline.run.stage import Stage
from pipeline.stages.encode import plan_encode, run_encode
from pipeline.stages.ingest import (
    plan_ingest,
    plan_select,
    plan_synth,
    run_ingest,
    run_select,
    run_synth,
)
from pipeline.stages.packets import plan_packets, run_packets
from pipeline.stages.report import plan_clips, plan_stats, run_clips, run_stats

STAGES: list[Stage] = [
    Stage("synth", (), plan_synth, run_synth, unit="recordings"),
    Stage("ingest", ("synth",), plan_ingest, run_ingest, unit="images"),
    Stage("select", ("ingest",), plan_select, run_select, unit="views"),
    Stage("encode", ("select",), plan_encode, run_encode, unit="views"),
    Stage("packets", ("select",), plan_packets, run_packets, unit="views"),
    Stage("stats", ("encode", "packets"), plan_stats, run_stats, unit="rows"),
    Stage("clips", ("stats",), plan_clips, run_clips, unit="clips"),
]


def stage_names() -> list[str]:
    """Names of the stages in graph order."""
    return [s.name for s in STAGES]
