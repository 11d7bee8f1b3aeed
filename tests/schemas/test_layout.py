"""OutputLayout: the on-disk names of a run's outputs (a contract: readers rely on them)."""

from __future__ import annotations

from pathlib import Path

from schemas.config import M3GDConfig
from schemas.layout import OutputLayout


def test_output_names_are_the_documented_ones() -> None:
    out = OutputLayout(Path("run"))
    assert out.cache == Path("run/cache.zarr")
    assert out.done == Path("run/cache_done")
    assert out.index_of("rec") == Path("run/index/rec")
    assert out.stats == Path("run/stats")
    assert out.clips == Path("run/clips.parquet")
    assert out.plots == Path("run/plots")
    assert out.bench == Path("run/bench")
    assert out.manifest == Path("run/manifest.json")
    assert out.recordings == Path("run/recordings")


def test_a_config_lays_out_its_output_dir() -> None:
    cfg = M3GDConfig(output_dir=Path("/data/out"))
    assert cfg.layout == OutputLayout(Path("/data/out"))
    labels = [label for label, _ in cfg.layout.outputs()]
    assert labels == ["cache", "index", "statistics", "clips", "plots", "manifest"]
