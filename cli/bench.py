"""`m3gd bench ...`: benchmarks that print ratios against baselines measured in one run.

The model benchmarks (`bench sampler`, `bench loader`, `bench science`) live with the model
commands (`cli.model`, `cli.model_bench`); `cli.app` attaches them to the same group. Each
benchmark module is imported by its command only: they pull in zarr, dask, open3d or torch.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from cli.common import emit, fail, stdout

HELP = "Benchmarks (ratios against baselines measured in the same run)."
JsonFlag = Annotated[bool, typer.Option("--json")]


def cache(as_json: JsonFlag = False, views: int = 512, workdir: Path | None = None,
          rss: Annotated[bool, typer.Option(help="Also measure worker peak RSS.")] = True
          ) -> None:
    """Sharded Zarr cache against one .npy file per view."""
    from bench.cache_bench import CacheBenchSpec, run_cache_bench
    from bench.packing_bench import run_packing_rss_bench

    result = run_cache_bench(CacheBenchSpec(views=views), workdir)
    if rss:
        result["peak_rss_gb_per_worker"] = run_packing_rss_bench(repeats=1)[
            "peak_rss_gb_per_worker"]
    emit(result, as_json, "bench cache")


def packets(as_json: JsonFlag = False, repeats: int = 5) -> None:
    """Packet pooling against the per-cell loop, torch index_add_ and the gather floor."""
    from bench.packets_bench import run_packets_bench

    emit(run_packets_bench(repeats), as_json, "bench packets")


def ingest(as_json: JsonFlag = False, seconds: float = 12.0) -> None:
    """Ingest against the rosbags + imdecode floor; peak RSS at twice the length."""
    from bench.ingest_bench import run_ingest_bench

    emit(run_ingest_bench(seconds), as_json, "bench ingest")


def packing(as_json: JsonFlag = False) -> None:
    """Peak RSS of one worker encoding and packing a 64k-point sweep at C_u=1224."""
    from bench.packing_bench import run_packing_rss_bench

    emit(run_packing_rss_bench(), as_json, "bench packing")


def dag(as_json: JsonFlag = False, seconds: float = 4.0, recordings: int = 4,
        packet_items: Annotated[str, typer.Option(
            help="packets.items: auto, recording or shard_row.")] = "auto",
        shard_views: Annotated[int, typer.Option(min=1)] = 64) -> None:
    """The stage graph on 2 Dask workers against 1, same recordings."""
    from bench.dag_bench import run_dag_bench
    from dags.graph import STAGES

    emit(run_dag_bench(STAGES, seconds, recordings, packet_items, shard_views), as_json,
         "bench dag")


def synth(as_json: JsonFlag = False, seconds: float = 20.0, scene: str = "corridor") -> None:
    """Synthetic recording generation against the raycasting floor, same run."""
    from bench.synth_bench import run as run_synth_bench

    emit(run_synth_bench(seconds, scene), as_json, "bench synth")


def tradeoffs(as_json: JsonFlag = False, seconds: float = 4.0, views: int = 60,
              workdir: Path | None = None) -> None:
    """What each speed / size knob saves and costs in depth accuracy (docs/tradeoffs.md)."""
    from bench.tradeoffs import run_tradeoffs

    emit(run_tradeoffs(workdir, seconds, max_views=views), as_json, "bench tradeoffs")


def costs(as_json: JsonFlag = False, runs: int = 3) -> None:
    """Per-item stage costs in one-thread workers, and the release estimate (scaling.md)."""
    from bench.scaling_report import run_costs_bench

    result = run_costs_bench(runs)
    if as_json:
        stdout.print_json(json.dumps({k: v for k, v in result.items() if k != "markdown"},
                                     default=str))
    else:
        stdout.print(result["markdown"], highlight=False, markup=False)


def fuzz(as_json: JsonFlag = False, cases: int = 40, seconds: float = 120.0, seed: int = 0,
         lock_trials: int = 3, lock_starts: int = 8, workdir: Path | None = None,
         compression: Annotated[str, typer.Option(help="chunks of the fuzzed bags: roslz4 "
                                "(rosbag record's LZ4, checksummed), lz4 (no checksum), none"
                                )] = "roslz4",
         variants: Annotated[str | None, typer.Option(
             help="comma-separated sensor variants the cases take turns on (`all`: every "
                  "one; default: the default recording)")] = None,
         hf_cases: Annotated[int, typer.Option(help="Hugging Face store cases (a cut or "
                                               "flipped chunk, ingested in a child process)"
                                               )] = 12,
         cache_flips: Annotated[int, typer.Option(
             help="cache chunks with flipped bits, read back by every reader")] = 50,
         ) -> None:  # fmt: skip
    """Damaged bags against their clean twin: crashes, silent losses, damage cached (goal 0)."""
    import tempfile

    from bench.fuzz import run_fuzz
    from pipeline.synth.variants import VARIANTS

    chosen = None
    if variants:
        chosen = list(VARIANTS) if variants == "all" else [
            v.strip() for v in variants.split(",") if v.strip()]
        unknown = sorted(set(chosen) - set(VARIANTS))
        if unknown:
            fail(f"unknown sensor variant(s) {unknown}; known: {', '.join(VARIANTS)}", 2)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        result = run_fuzz(Path(tmp), cases, seconds, seed, lock_trials, lock_starts,
                          compression, chosen, hf_cases, cache_flips)  # type: ignore[arg-type]
    emit(result, as_json, "bench fuzz")


def storage(as_json: JsonFlag = False, output: Annotated[Path | None, typer.Option(
        help="A pipeline output dir; default: build a tiny one in a temporary directory."
        )] = None, rounds: Annotated[int, typer.Option(min=1)] = 3) -> None:
    """Clip reads from S3 (a local moto server) against local disk; requests per clip."""
    from bench.storage_bench import run
    from dags.graph import STAGES

    emit(run(STAGES, output, rounds), as_json, "bench storage")


def variants(as_json: JsonFlag = False,
             names: Annotated[str | None, typer.Option(
                 "--only", help="comma-separated variant names (default: all)")] = None,
             seconds: float = 3.0, workdir: Path | None = None) -> None:
    """Every sensor variant through synth, ingest, select, packets and accuracy: false rejects,
    views kept against the default synth, depth abs-rel, silent losses."""
    import tempfile

    from bench.variants import run_variants

    chosen = [n.strip() for n in names.split(",") if n.strip()] if names else None
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        result = run_variants(Path(tmp), chosen, {"seconds": seconds})
    emit(result, as_json, "bench variants")


def view(as_json: JsonFlag = False,
         seconds: float = 10.0, points: int = 16384, repeats: int = 3) -> None:
    """Writing the .rrd of a recording against reading its views from the cache."""
    from bench.view_bench import run_view_bench
    from dags.graph import STAGES

    emit(run_view_bench(STAGES, seconds, points, repeats), as_json, "bench view")
