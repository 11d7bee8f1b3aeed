"""The Parquet tables reference: every schema of `schemas/tables.py` and
`schemas/recording_index.py`, as Markdown (column, Arrow type, nullable)."""

from __future__ import annotations

import pyarrow as pa

from model.evaluate import BASELINES, REPROJ_CANDIDATES
from schemas import recording_index as ri
from schemas import tables as st
from schemas.versioning import KIND_KEY, VERSION_KEY

INDEX_PATH = "out/index/<recording>/{name}.parquet"

# (name, schema, where it lives, which command writes it, what a row is)
TABLES: list[tuple[str, pa.Schema, str, str, str]] = [
    ("images", ri.IMAGES, INDEX_PATH.format(name="images"), "`m3gd run` (ingest)",
     "one row per kept camera image"),
    ("sweeps", ri.SWEEPS, INDEX_PATH.format(name="sweeps"), "`m3gd run` (ingest)",
     "one row per kept LiDAR sweep"),
    ("odometry", ri.ODOMETRY, INDEX_PATH.format(name="odometry"), "`m3gd run` (ingest)",
     "one row per kept odometry pose"),
    ("calibration", ri.CALIBRATION, INDEX_PATH.format(name="calibration"),
     "`m3gd run` (ingest)", "one row per sensor"),
    ("rejects", ri.REJECTS, INDEX_PATH.format(name="rejects"), "`m3gd run` (ingest)",
     "one row per rejected message or problem, with its reason code"),
    ("damage", ri.DAMAGE, INDEX_PATH.format(name="damage"), "`m3gd run` (ingest)",
     "one row per unreadable byte range of a bag"),
    ("accounting", ri.ACCOUNTING, INDEX_PATH.format(name="accounting"), "`m3gd run` (ingest)",
     "per bag file and topic: read = kept + rejected"),
    ("checks", ri.CHECKS, INDEX_PATH.format(name="checks"), "`m3gd run` (ingest)",
     "one row per plausibility check and topic it ran on: state, messages judged, flagged, "
     "rejected and trusted"),
    ("geometry", ri.GEOMETRY, INDEX_PATH.format(name="geometry"), "`m3gd run` (geometry)",
     "one row per camera: the geometry verdict (ok, inconclusive, failed), its reason and "
     "likely cause, the LiDAR-edge score beside its shuffled-pairs null"),
    ("selection", ri.SELECTION, INDEX_PATH.format(name="selection"), "`m3gd run` (select)",
     "one row per view, rejected ones included"),
    ("selection_lidars", ri.SELECTION_LIDARS, INDEX_PATH.format(name="selection_lidars"),
     "`m3gd run` (select), when `select.lidar` merges several LiDARs",
     "one row per view and merged LiDAR: that LiDAR's own nearest sweep, delta tau and "
     "camera-from-LiDAR transform"),
    ("view_stats", st.VIEW_STATS, "out/stats/view_stats/<recording>.parquet",
     "`m3gd run` (stats)", "one row per view"),
    ("cell_stats", st.CELL_STATS, "out/stats/cell_stats/<recording>.parquet",
     "`m3gd run` (stats)", "one row per occupied packet cell"),
    ("clips", st.CLIPS, "out/clips.parquet", "`m3gd run` (clips)",
     "one row per training or evaluation clip"),
    ("alignment", st.ALIGNMENT, "out/stats/alignment.parquet", "`m3gd align`",
     "one row per feature pair and metric, beside its permutation null"),
    ("accuracy", st.ACCURACY, "out/stats/accuracy/<recording>.parquet",
     "`m3gd accuracy`",
     "one row per occupied packet cell of an accepted view, against ground truth"),
    ("eval_targets", st.eval_targets_schema(BASELINES, REPROJ_CANDIDATES),
     "out/train/<mode>/eval.parquet (beside eval.json)", "`m3gd eval`",
     "one row per scored target view: the model's and every baseline's PSNR and SSIM"),
    ("reprojection_consistency", st.REPROJECTION_CONSISTENCY,
     "out/stats/reprojection_consistency.parquet", "`m3gd align --consistency`",
     "one row per recording and camera: the clock offset and extrinsic rotation recovered "
     "from its views' photometric agreement on LiDAR points"),
]


def _meta(schema: pa.Schema) -> tuple[str, str]:
    meta = schema.metadata or {}
    return (meta.get(KIND_KEY.encode(), b"").decode(), meta.get(VERSION_KEY.encode(), b"").decode())


def _reasons() -> list[str]:
    return [f"- `{r.value}`" + (" (drops one message)" if r in ri.MESSAGE_REASONS else "")
            for r in ri.Reason]


def render() -> str:
    """The Parquet tables page (Markdown)."""
    out = [
        "# Parquet tables",
        "",
        "Generated from `schemas/tables.py` and `schemas/recording_index.py` each time the site",
        "is built. Every file carries its kind and format version in the Arrow schema metadata",
        f"(`{KIND_KEY}`, `{VERSION_KEY}`); readers refuse an unknown version with one line.",
        "Stamps are int64 nanoseconds, durations float64 seconds, transforms row-major 4×4",
        "float64 (`T_a_b` maps b coordinates into a), intrinsics row-major 3×3. Any Parquet",
        "reader opens them; `m3gd stats query` runs DuckDB SQL over the statistics tables.",
        "",
        f"A table of several recordings (layout version {st.STATS_LAYOUT_VERSION}) is a folder",
        "of one file per recording, `<table>/<recording>.parquet`, with no hive folder: the",
        "`recording` column (a string) is in every file. pandas, pyarrow, polars and DuckDB",
        "open the folder with no option and agree on its rows and types, for example",
        "`pandas.read_parquet(\"out/stats/view_stats\")`,",
        "`polars.read_parquet(\"out/stats/view_stats\")` or",
        "`duckdb.read_parquet(\"out/stats/view_stats\")`; the index tables are one file each.",
        "(Layout version 1 held `recording=<rec>/` folders over files that also had the",
        "column, which pandas and pyarrow refused to merge; `m3gd run` and `m3gd accuracy`",
        "rewrite them.)",
        "",
        "| table | path | written by | a row is |",
        "|---|---|---|---|",
    ]
    out += [f"| [`{n}`](#{n}) | `{p}` | {w} | {r} |" for n, _, p, w, r in TABLES]
    out.append("")
    for name, schema, path, writer, row in TABLES:
        kind, version = _meta(schema)
        out += [f"## `{name}`", "", f"`{path}`, written by {writer}: {row}. Kind `{kind}`, "
                f"format version {version}.", "",
                "| column | Arrow type | nullable |", "|---|---|---|"]
        out += [f"| `{f.name}` | `{f.type}` | {'yes' if f.nullable else 'no'} |" for f in schema]
        out.append("")
    out += ["## Reject reason codes", "",
            "The `reason` column of `rejects` and of rejected rows of `selection`:", "",
            *_reasons(), ""]
    return "\n".join(out)
