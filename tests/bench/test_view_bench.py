"""View benchmark: its parts on the tiny output, the whole at a tiny size (no timing asserts)."""

from __future__ import annotations

import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from bench import view_bench
from dags.graph import STAGES
from schemas.config import M3GDConfig
from tests.pipeline.tiny_output import tiny_output


@pytest.fixture(scope="module")
def cfg(tmp_path_factory: pytest.TempPathFactory) -> M3GDConfig:
    return tiny_output(tmp_path_factory)


def test_the_read_baseline_reads_every_view(cfg: M3GDConfig) -> None:
    views = view_bench._read_all(cfg)
    images = pq.read_metadata(cfg.output_dir / "index" / "t_view" / "images.parquet").num_rows
    assert views == images


def test_the_sweep_timing_decodes_each_selected_sweep_once(cfg: M3GDConfig) -> None:
    sel = pq.read_table(cfg.output_dir / "index" / "t_view" / "selection.parquet").to_pylist()
    n = view_bench._decode_sweeps(cfg)
    assert n == len({r["sweep"] for r in sel if r["status"] == "ok"}) > 0


def test_peak_rss_child_writes_the_view(cfg: M3GDConfig, tmp_path: Path) -> None:
    out = view_bench.peak_rss_mb(cfg, tmp_path / "x.rrd", 0.5)
    assert (tmp_path / "x.rrd").stat().st_size > 0
    assert out["peak_mb"] >= out["base_mb"] > 0


@pytest.mark.slow
def test_whole_bench_at_a_tiny_size() -> None:
    out = view_bench.run_view_bench(STAGES, seconds=1.0, points=1024, repeats=1)
    assert out["views"] > 0 and out["sweeps"] > 0
    assert all(math.isfinite(v) and v > 0 for k, v in out.items() if not k.startswith("rss_inc"))
