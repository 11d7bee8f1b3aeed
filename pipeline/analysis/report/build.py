"""Build the report page of an output directory and write it atomically."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from pipeline.analysis.figures import make_plots
from pipeline.analysis.report import sections
from pipeline.analysis.report.geometry_section import geometry
from pipeline.analysis.report.html import Section, note, page
from pipeline.run.lock import running_holder
from schemas.atomic_io import write_text_atomic
from schemas.layout import OutputLayout

MAX_ROWS = 200


@dataclass
class ReportResult:
    """The written page, its size, its sections and what was made or left out on the way."""

    path: Path
    bytes: int
    sections: list[str]
    messages: list[str] = field(default_factory=list)


def build_report(output_dir: Path, out: Path | None = None, *, plots: bool = True,
                 max_rows: int = MAX_ROWS, dtau_bound_s: float | None = None) -> ReportResult:
    """Write `<output_dir>/report.html` (or `out`): run summary, rejects, Δτ and occupancy,
    alignment beside its nulls, the accuracy summary, benchmark figures and plots, then the
    raw rows of every other statistics table (collapsed), in one static page.

    plots: write the analyst plots first, as `m3gd plot` does (`dtau_bound_s`, the select
    stage's |Δτ| bound, drawn on the Δτ histograms); without, the PNGs already under `plots/`
    are embedded as they are. max_rows: rows shown per listed table. FileNotFoundError when
    `output_dir` is not a folder.
    """
    if not output_dir.is_dir():
        raise FileNotFoundError(f"{output_dir}: no output directory; run the pipeline first")
    messages = []
    writing = running_holder(output_dir)
    if writing is not None:
        messages.append(f"{output_dir} is still being written by an m3gd run "
                        f"({writing.describe()}): the report shows it incomplete")
    if plots:
        made = make_plots(output_dir, dtau_bound_s)
        messages.append(f"wrote {len(made)} plot(s) under {OutputLayout(output_dir).plots} first")
    summaries = [sections.run_summary(output_dir), geometry(output_dir),
                 sections.rejects(output_dir),
                 sections.dtau_occupancy(output_dir), sections.alignment(output_dir),
                 sections.accuracy(output_dir), sections.benchmarks(output_dir),
                 sections.plots(output_dir)]
    # summaries and plots first, raw rows after
    parts: list[Section] = [*(s for s in summaries if s is not None),
                            *sections.extra_tables(output_dir, max_rows)]
    if writing is not None:
        parts.insert(0, Section("incomplete", "Incomplete: a run is still writing this output",
                                note(f"an m3gd run ({writing.describe()}) holds the lock of "
                                     f"{output_dir}: stages may be unfinished and tables "
                                     "partial; make the report again when it has ended")))
    html = page(f"m3gd run report: {output_dir.name}", parts, f"output directory {output_dir}")
    path = write_text_atomic(out or OutputLayout(output_dir).report, html)
    return ReportResult(path, path.stat().st_size, [s.id for s in parts], messages)


def run_report(output_dir: Path, out: Path | None = None, plots: bool = True,
               dtau_bound_s: float | None = None) -> list[str]:
    """Write the report page; the lines to print (what was made, where the page is)."""
    result = build_report(output_dir, out, plots=plots, dtau_bound_s=dtau_bound_s)
    return [*result.messages, f"wrote {result.path} ({result.bytes / 1e6:.1f} MB, "
            f"{len(result.sections)} sections); open it in any browser, it needs no server"]
