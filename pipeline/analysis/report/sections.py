"""The sections of the report, each read from one part of an output directory.

Aggregates run in DuckDB over the Parquet files (streamed, not loaded whole); listed tables
show at most `max_rows` rows and say how many they left out. A part that is missing yields a
note instead of a table, never an error: the report describes whatever a run has produced.
"""

from __future__ import annotations

import datetime as dt
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from pipeline.analysis.accuracy import SUMMARY_FILE as ACCURACY_SUMMARY
from pipeline.analysis.align import ALIGNMENT_FILE
from pipeline.analysis.query import check_table, query, summary
from pipeline.analysis.report.accuracy_tables import groupings, overall
from pipeline.analysis.report.html import (
    Section,
    collapsed,
    figure,
    groups,
    kv_table,
    note,
    table_html,
)
from pipeline.stats.merge import LATENT_PARTS
from pipeline.stats.rows import PARTS_DIR
from schemas.layout import OutputLayout
from schemas.manifest import read_manifest
from schemas.recording_index import SELECTION_FILE
from schemas.stages import STAGE_ORDER
from schemas.tables import ALIGNMENT, read_table

KNOWN_STATS = {"view_stats", "cell_stats", PARTS_DIR, LATENT_PARTS,
               ALIGNMENT_FILE.removesuffix(".parquet")}
"""Entries of `stats/` with a section of their own (or intermediate parts); any other Parquet
table there is listed generically (accuracy, trade-off tables, ...)."""

OCCUPANCY_SQL = """
    SELECT recording, camera, count(*) AS views,
           round(avg(supported_cells), 3) AS mean_supported_cells,
           min(supported_cells) AS min_supported_cells,
           max(supported_cells) AS max_supported_cells,
           round(avg(points_in_frustum), 1) AS mean_points_in_frustum,
           count(*) FILTER (WHERE supported_cells < 3) AS sparse_views
    FROM view_stats WHERE reject_reason IS NULL
    GROUP BY recording, camera ORDER BY recording, camera"""
"""Per recording and camera, over accepted views: LiDAR-supported cells per view."""


def _when(unix_s: float | None) -> str:
    """A Unix time as UTC ISO text ('' when unknown)."""
    if unix_s is None:
        return ""
    return dt.datetime.fromtimestamp(unix_s, dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _rows(path: Path) -> int:
    """Row count of a Parquet file from its footer (0 when missing)."""
    return pq.ParquetFile(path).metadata.num_rows if path.exists() else 0


def run_summary(out: Path) -> Section:
    """Manifest (config hash, versions, stages) and per-recording index counts."""
    parts = []
    manifest = read_manifest(out)
    if manifest is None:
        parts.append(note(f"{out}: no manifest.json (no run has finished a stage here)"))
    else:
        run: list[tuple[str, object]] = [
            ("output directory", out), ("config hash", manifest.config_hash),
            ("code version", manifest.code_version),
            ("created", _when(manifest.created_unix_s))]
        if manifest.inputs:  # identities of recorded inputs (none for synthetic recordings)
            run.append(("input files", len(manifest.inputs)))
        stages = _stage_table(manifest.stages, manifest.created_unix_s)
        parts.append(groups([kv_table(run, "t-run", "run"),
                             table_html(stages, "t-stages", "stages, in pipeline order")]))
        parts.append(collapsed(f"packages ({len(manifest.packages)})", kv_table(
            sorted(manifest.packages.items()), "t-packages", "packages")))
    recs = sorted(p for p in OutputLayout(out).index.glob("*") if p.is_dir())
    if recs:
        parts.append(table_html(_recording_counts(recs), "t-recordings", "recordings"))
    return Section("summary", "Run summary", "".join(parts))


PIPELINE_ORDER = STAGE_ORDER
"""The stages in the order the stage graph runs them (the stage table, `schemas.stages`)."""


def _stage_table(records: dict[str, Any], created_unix_s: float | None) -> pa.Table:
    """One row per stage in pipeline order (others after, by finish time): items done, when
    it last finished, and the seconds since the stage before it finished (the run's start for
    the first): its wall time on a run that did every stage in one go."""
    shown = {n: r for n, r in records.items() if not n.startswith("_")}  # `_…`: bookkeeping
    known = [n for n in PIPELINE_ORDER if n in shown]
    rest = sorted((n for n in shown if n not in PIPELINE_ORDER),
                  key=lambda n: shown[n].finished_unix_s or 0.0)
    names = known + rest
    seconds: list[float | None] = []
    before = created_unix_s
    for n in names:
        end = shown[n].finished_unix_s
        seconds.append(None if end is None or before is None else round(end - before, 1))
        before = end if end is not None else before
    return pa.table({"stage": names, "items done": [len(shown[n].items) for n in names],
                     "finished": [_when(shown[n].finished_unix_s) for n in names],
                     "seconds after the previous": pa.array(seconds, pa.float64())})


def _recording_counts(recs: list[Path]) -> pa.Table:
    """Images, sweeps, odometry samples, rejects and accepted views of each recording."""
    rows = []
    for rec in recs:
        sel = rec / SELECTION_FILE
        ok = None
        if sel.exists():
            status = pq.read_table(sel, columns=["status"])["status"].to_numpy(
                zero_copy_only=False)
            ok = int(np.sum(status == "ok"))
        rows.append({"recording": rec.name, "images": _rows(rec / "images.parquet"),
                     "sweeps": _rows(rec / "sweeps.parquet"),
                     "odometry samples": _rows(rec / "odometry.parquet"),
                     "rejected messages": _rows(rec / "rejects.parquet"),
                     "accepted views": ok})
    return pa.Table.from_pylist(rows)


def rejects(out: Path) -> Section:
    """Dropped messages by recording, topic and reason; rejected views by reason."""
    parts = []
    counts = [pq.read_table(f, columns=["topic", "reason"]).group_by(["topic", "reason"])
              .aggregate([("reason", "count")]).sort_by([("topic", "ascending"),
                                                          ("reason", "ascending")])
              for f in sorted(OutputLayout(out).index.glob("*/rejects.parquet"))]
    recs = [f.parent.name for f in sorted(OutputLayout(out).index.glob("*/rejects.parquet"))]
    if counts:
        table = pa.concat_tables([
            pa.table({"recording": [r] * c.num_rows, "topic": c["topic"], "reason": c["reason"],
                      "messages": c["reason_count"]}) for r, c in zip(recs, counts, strict=True)])
        parts.append(table_html(table, "t-rejects", "dropped messages (rejects.parquet)")
                     if table.num_rows else note("dropped messages: none"))
    else:
        parts.append(note("no rejects table (ingest has not run)"))
    checks = check_table(out)
    if checks is not None and checks.num_rows:
        parts.append(collapsed(f"plausibility checks per topic ({checks.num_rows} rows)",
                               table_html(checks, "t-checks", "plausibility checks per topic "
                                          "(checks.parquet; off: its model did not fit the "
                                          "stream, capped: it stopped rejecting at its share)")))
    views = _summary_or_none(out, "rejects")
    if views is not None:
        parts.append(table_html(views, "t-rejected-views", "rejected views (view_stats)"))
    return Section("rejects", "Rejects", "".join(parts))


def _summary_or_none(out: Path, name: str) -> pa.Table | None:
    """A canned statistics summary, or None when the statistics are not written yet."""
    if not any((OutputLayout(out).stats / "view_stats").glob("*.parquet")):
        return None
    return summary(out, name)


def dtau_occupancy(out: Path) -> Section:
    """Δτ statistics and LiDAR support per recording and camera."""
    dtau = _summary_or_none(out, "dtau")
    if dtau is None:
        return Section("dtau", "Δτ and occupancy",
                       note("no view statistics yet (run the packets and stats stages)"))
    occ = query(out, OCCUPANCY_SQL)
    body = (table_html(dtau, "t-dtau", "Δτ = sweep stamp − image stamp, per recording and "
                       "camera (ms)")
            + table_html(occ, "t-occupancy", "LiDAR-supported latent cells per accepted view"))
    return Section("dtau", "Δτ and occupancy", body)


def alignment(out: Path) -> Section:
    """The 2D–3D alignment table, each metric beside its permutation null."""
    path = OutputLayout(out).stats / ALIGNMENT_FILE
    if not path.exists():
        return Section("alignment", "2D–3D alignment",
                       note("no alignment table (run `m3gd align`)"))
    t = read_table(path, ALIGNMENT)
    value, null = t["value"].to_numpy(), t["null_value"].to_numpy()
    t = t.append_column("value − null", pa.array(value - null, pa.float64()))
    cols = ["pair", "metric", "value", "null_value", "value − null", "images", "excluded_images"]
    return Section("alignment", "2D–3D alignment", table_html(
        t.select(cols), "t-alignment", "macro mean over images beside the mean of the "
        "permutation null (cells shuffled within each image)"))


PLOT_CAPTIONS = {
    "dtau_hist": "Δτ = sweep stamp − image stamp per camera; the select stage's bound dashed",
    "occupancy": "How often each latent cell has LiDAR support, over the accepted views",
    "depth_hist": "Mean depth of the supported cells",
    "speed_accuracy": "Sampler speed against accuracy (m3gd bench sampler)",
    "accuracy_vs_dtau": "Packet depth error (abs-rel) of each view against its |Δτ|",
    "accuracy_map": "Packet depth error per cell of the view with the most supported cells",
    "science_loss": "Science bench: training and validation loss",
    "science_trade": "Science bench: PSNR and SSIM against seconds per target",
    "science_modes": "Science bench: held-out PSNR per packet mode over seeds",
    "science_reproj": "Science bench: reprojection consistency of the synthesized targets per "
                      "packet mode, beside the ground truth (the floor) and the baselines",
    "reprojection_consistency": "Reprojection consistency per recording/camera (m3gd align "
                                "--consistency): photometric error at the recorded "
                                "calibration and at the estimate; recovered clock offset and "
                                "rotation against the injected ones where known (y = x: "
                                "exact recovery)",
}
"""Caption of each plot `m3gd plot`, `m3gd accuracy` and the benches write, by file stem."""
_PCA = re.compile(r"pca_(?P<rest>.+)_(?P<frame>\d{5})")


def plot_caption(stem: str) -> str:
    """What a plot shows, from its file stem (the stem itself for a plot of unknown kind)."""
    if stem in PLOT_CAPTIONS:
        return PLOT_CAPTIONS[stem]
    if stem.startswith("train_"):
        return (f"Training run {stem.removeprefix('train_')}: loss, gradient norm and learning "
                "rate, updates per second, and PSNR beside the baselines, against the update")
    pca = _PCA.fullmatch(stem)
    if pca is not None:
        return (f"Image, latent PCA and point-feature PCA of {pca['rest']} frame "
                f"{int(pca['frame'])}")
    return f"Plot {stem.replace('_', ' ')}"


def plots(out: Path) -> Section:
    """Every PNG under `plots/`, embedded with its caption."""
    pngs = sorted(OutputLayout(out).plots.glob("*.png"))
    if not pngs:
        return Section("plots", "Plots", note("no plots (run `m3gd plot`)"))
    return Section("plots", "Plots", "".join(
        figure(p.read_bytes(), plot_caption(p.stem), p.stem, wide=p.stem.startswith("train_"))
        for p in pngs))


def accuracy(out: Path) -> Section | None:
    """The accuracy summary (stats/accuracy_summary.json) as a table, before the raw rows
    (None when `m3gd accuracy` has not run)."""
    path = OutputLayout(out).stats / ACCURACY_SUMMARY
    if not path.exists():
        return None
    data = json.loads(path.read_text())
    tables = [kv_table(overall(data), "t-accuracy-summary", "overall")]
    for g in groupings(data):
        empty = f" (no cell: {', '.join(g.empty_bins)})" if g.empty_bins else ""
        tables.append(table_html(g.table, f"t-accuracy-{g.key}", g.title + empty))
    return Section("accuracy", "Packet accuracy against ground truth", note(
        "summary of `m3gd accuracy` (accuracy_summary.json); the per-cell rows are under "
        "Table: accuracy") + groups(tables))


def extra_tables(out: Path, max_rows: int) -> list[Section]:
    """Any other Parquet table under `stats/` (a file, or a folder of files), listed as is."""
    stats = OutputLayout(out).stats
    found: dict[str, list[Path]] = {}
    for path in sorted(stats.rglob("*.parquet")) if stats.exists() else []:
        name = path.relative_to(stats).parts[0].removesuffix(".parquet")
        if name not in KNOWN_STATS and not name.startswith("."):
            found.setdefault(name, []).append(path)
    sections = []
    for name, files in found.items():
        data = ds.dataset([str(f) for f in files], format="parquet")
        total = data.count_rows()
        shown = f"first {max_rows} of {total}" if total > max_rows else f"all {total}"
        sections.append(Section(f"table-{name}", f"Table: {name}", collapsed(
            f"raw rows of stats/{name} ({shown} rows)",
            table_html(data.head(max_rows), f"t-{name}", f"stats/{name}", total))))
    return sections


def benchmarks(out: Path) -> Section | None:
    """Scalar figures of every benchmark JSON kept under `bench/` (None when there is none)."""
    files = sorted(OutputLayout(out).bench.glob("*.json"))
    if not files:
        return None
    parts = []
    for f in files:
        raw = json.loads(f.read_text())
        pairs = [(k, v) for k, v in raw.items() if isinstance(v, (int, float, str, bool))]
        parts.append(kv_table(pairs, f"t-bench-{f.stem}", f"bench {f.stem}"))
    return Section("bench", "Benchmarks", "".join(parts))
