"""The science suites behind `m3gd bench science` (bench/cli.py): the paper's controls
(`--suite paper`, `paper-cpu`) and the data-scaling table (`--recordings`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from cli.common import emit, fail

if TYPE_CHECKING:
    from bench.science import SciencePreset
    from schemas.config import M3GDConfig


def paper_suite(cfg: M3GDConfig, preset: SciencePreset, quick: bool, cpu: bool,
           workdir: Path | None, cache: Path | None, jobs: int, train_missing: bool,
           as_json: bool, steps: int | None, seeds: int | None,
           rows: str | None = None, device: str = "cpu") -> None:
    """`m3gd bench science --suite paper`: the suite on `preset` (QUICK_PAPER's M and K grid
    with --quick; CPU_PAPER's data, network and budget with paper-cpu, --steps and --seeds
    still applying), results in <workdir>/paper.json and
    <output_dir>/bench/science_paper.json."""
    from dataclasses import replace

    from bench.science_paper import (
        CPU_PAPER,
        PAPER_HEADLINE,
        QUICK_PAPER,
        PaperSuite,
        run_paper,
        with_rows,
    )
    from dags.graph import STAGES
    from pipeline.analysis.figures import save_bench

    suite = (replace(QUICK_PAPER, preset=preset) if quick else
             CPU_PAPER if cpu else PaperSuite(preset))
    if cpu and steps is not None:
        spec = suite.preset.spec
        suite = replace(suite, preset=replace(suite.preset, spec=replace(
            spec, steps=steps, val_every=max(1, min(spec.val_every, steps // 2)))))
    if cpu and seeds is not None:
        suite = replace(suite, preset=replace(suite.preset, seeds=tuple(range(seeds))))
    suite = replace(suite, preset=replace(suite.preset, spec=replace(suite.preset.spec,
                                                                    device=device)))
    if rows is not None:
        try:
            suite = with_rows(suite, [r.strip() for r in rows.split(",") if r.strip()])
        except ValueError as err:
            fail(f"--rows: {err}")
    result = run_paper(suite, (workdir or cfg.layout.science) / "paper", STAGES, cache, jobs,
                       train_missing)
    save_bench(cfg.output_dir, "science_paper", result)
    emit({k: result[k] for k in PAPER_HEADLINE if k in result}, as_json, "bench science paper")


def ints(text: str, option: str) -> list[int]:
    """Comma-separated positive integers of `option` (a usage error otherwise)."""
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        fail(f"{option} {text!r}: comma-separated integers")
    if not values or min(values) < 1:
        fail(f"{option} {text!r}: comma-separated integers >= 1")
    return values


def scaling_table(cfg: M3GDConfig, workdir: Path | None, jobs: int, train_missing: bool,
             as_json: bool, recordings: str, point_seeds: str | None, rows: str | None,
             steps: int | None, device: str) -> None:
    """`m3gd bench science --suite paper-cpu --recordings 8,32,128`: the data-scaling table
    (`bench.science_scaling`), in <workdir>/scaling/scaling.json and
    <output_dir>/bench/science_scaling.json."""
    from dataclasses import replace

    from bench.science_paper import CPU_PAPER
    from bench.science_scaling import ROWS, run_scaling, scaling_suite
    from dags.graph import STAGES
    from pipeline.analysis.figures import save_bench

    spec = replace(CPU_PAPER.preset.spec, device=device)
    if steps is not None:
        spec = replace(spec, steps=steps, val_every=max(1, min(spec.val_every, steps // 2)))
    paper = replace(CPU_PAPER, preset=replace(CPU_PAPER.preset, spec=spec))
    names = ROWS if rows is None else [r.strip() for r in rows.split(",") if r.strip()]
    try:
        suite = scaling_suite(ints(recordings, "--recordings"),
                              None if point_seeds is None else ints(point_seeds,
                                                                     "--point-seeds"),
                              names, paper)
    except ValueError as err:
        fail(f"--recordings: {err}")
    result = run_scaling(suite, (workdir or cfg.layout.science) / "scaling", STAGES, jobs,
                         train_missing)
    save_bench(cfg.output_dir, "science_scaling", result)
    emit({"series": result.get("series", {}), "wall_minutes": result.get("wall_minutes")},
         as_json, "bench science scaling")
