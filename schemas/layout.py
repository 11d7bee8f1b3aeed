"""Where a run's outputs live under its output root: one object names every one of them.

    <root>/recordings/<mission>/   synthesized recordings (when none is configured)
    <root>/index/<recording>/      recording index tables (Parquet)
    <root>/cache.zarr/             the training cache (Zarr v3)
    <root>/cache_done/             per-shard completion marks beside the cache
    <root>/stats/                  statistics tables (Parquet, hive-partitioned)
    <root>/clips.parquet           the clip index
    <root>/plots/                  analyst plots (PNG)
    <root>/bench/                  benchmark results that the plots draw (JSON)
    <root>/manifest.json           the run manifest
    <root>/train/<mode>/           training runs and checkpoints (`m3gd train`)
    <root>/view/<recording>.rrd    Rerun recordings (`m3gd view`)
    <root>/science/                the science bench's runs (`m3gd bench science`)
    <root>/report.html             the HTML report (`m3gd report`)

Every path is the root joined with these names, and nothing here touches storage, so a
root of another path type with the same `/` operator (an object-storage path such as a
universal-pathlib `UPath`) can later stand in for a local `Path`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

RECORDINGS_DIRNAME = "recordings"
INDEX_DIRNAME = "index"
CACHE_DIRNAME = "cache.zarr"
DONE_DIRNAME = "cache_done"
STATS_DIRNAME = "stats"
CLIPS_FILENAME = "clips.parquet"
PLOTS_DIRNAME = "plots"
BENCH_DIRNAME = "bench"
MANIFEST_FILENAME = "manifest.json"
TRAIN_DIRNAME = "train"
VIEW_DIRNAME = "view"
SCIENCE_DIRNAME = "science"
REPORT_FILENAME = "report.html"


@dataclass(frozen=True)
class OutputLayout:
    """The outputs of one run under `root` (the configured output_dir)."""

    root: Path

    @property
    def recordings(self) -> Path:
        """Folder of the synthesized mission folders."""
        return self.root / RECORDINGS_DIRNAME

    @property
    def index(self) -> Path:
        """Folder of the per-recording index folders."""
        return self.root / INDEX_DIRNAME

    def index_of(self, recording: str) -> Path:
        """Index folder of one recording."""
        return self.index / recording

    @property
    def cache(self) -> Path:
        """The Zarr cache store."""
        return self.root / CACHE_DIRNAME

    @property
    def done(self) -> Path:
        """Folder of the shard completion marks (beside the cache: Zarr readers never see it)."""
        return self.root / DONE_DIRNAME

    @property
    def stats(self) -> Path:
        """Folder of the statistics tables."""
        return self.root / STATS_DIRNAME

    @property
    def clips(self) -> Path:
        """The clip index table."""
        return self.root / CLIPS_FILENAME

    @property
    def plots(self) -> Path:
        """Folder of the analyst plots."""
        return self.root / PLOTS_DIRNAME

    @property
    def bench(self) -> Path:
        """Folder of saved benchmark results that `m3gd plot` draws."""
        return self.root / BENCH_DIRNAME

    @property
    def manifest(self) -> Path:
        """The run manifest."""
        return self.root / MANIFEST_FILENAME

    @property
    def train(self) -> Path:
        """Folder of the training runs, one sub-folder per packet mode."""
        return self.root / TRAIN_DIRNAME

    def train_of(self, mode: str) -> Path:
        """Default folder of a training run (and its checkpoint) in packet mode `mode`."""
        return self.train / mode

    @property
    def view(self) -> Path:
        """Folder of the Rerun recordings (.rrd) of `m3gd view`."""
        return self.root / VIEW_DIRNAME

    @property
    def science(self) -> Path:
        """Default work folder of `m3gd bench science`."""
        return self.root / SCIENCE_DIRNAME

    @property
    def report(self) -> Path:
        """Default path of the HTML report."""
        return self.root / REPORT_FILENAME

    def outputs(self) -> list[tuple[str, Path]]:
        """(label, path) of the outputs a user looks at, in the order `m3gd demo` lists them."""
        return [("cache", self.cache), ("index", self.index), ("statistics", self.stats),
                ("clips", self.clips), ("plots", self.plots), ("manifest", self.manifest)]
