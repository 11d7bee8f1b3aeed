"""One tiny pipeline output (tests only), built once per test session: a 2 s synthetic
recording with a corrupt JPEG and a LiDAR gap (so rejects exist), run through every stage with
the DAG tests' tiny config, in-process. Used by the view and report tests."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from schemas.config import M3GDConfig, SynthConfig
from tests.dags.conftest import synth_config, tiny_config

FAULTS = ["corrupt_jpeg", "lidar_gap"]


def tiny_output(factory: pytest.TempPathFactory) -> M3GDConfig:
    """Config of the session's tiny output (run on first use; later calls reuse it)."""
    from dags.graph import STAGES
    from pipeline.run.service import run_stages
    from pipeline.synth.api import synthesize

    base = factory.getbasetemp() / "tiny_output"
    mission = base / "recordings" / "t_view"
    cfg = tiny_config(base / "out", [mission])
    if (cfg.output_dir / "clips.parquet").exists():
        return cfg
    raw = synth_config().model_dump()
    synthesize(mission.parent, SynthConfig(**{**raw, "faults": FAULTS}), "corridor",
               mission="t_view")
    summaries = run_stages(cfg, STAGES).summaries
    assert all(not s.failed for s in summaries), [s.failed for s in summaries]
    return cfg


def stats_rows(cfg: M3GDConfig, name: str) -> list[dict[str, object]]:
    """Rows of a merged statistics table (its file per recording)."""
    files = sorted((cfg.output_dir / "stats" / name).glob("*.parquet"))
    return pa.concat_tables([pq.read_table(f) for f in files]).to_pylist()
