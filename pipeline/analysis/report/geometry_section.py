"""The report's geometry section: each camera's verdict after packets
(`index/*/geometry.parquet`)."""

from __future__ import annotations

from pathlib import Path

import pyarrow.compute as pc

from pipeline.analysis.geometry_check import geometry_table
from pipeline.analysis.report.html import Section, note, table_html

COLUMNS = ("recording", "camera", "verdict", "reason", "cause", "accepted", "views",
           "edge_points", "score", "null_mean", "null_std", "z", "best_score", "best_moved")
"""The columns shown (the table's p value and wins stay in the file)."""


def geometry(out: Path) -> Section:
    """One row per camera: the verdict, why, the likely cause of a failure, the score beside
    its shuffled-pairs null; a note when no run has judged the geometry."""
    table = geometry_table(out)
    if table is None:
        return Section("geometry", "Geometry verdict",
                       note("no geometry verdict (the geometry stage has not run)"))
    failed = int(pc.sum(pc.equal(table["verdict"], "failed")).as_py() or 0)
    head = note(f"{table.num_rows} camera(s); {failed} failed. The LiDAR-edge score of each "
                "view's own image against the same score on other views' images (the "
                "shuffled-pairs null): ok when it stands out and the views agree where they "
                "overlap (each view's LiDAR edges read in its neighbours' images), failed "
                "when it does not with ample evidence, a small rotation, translation or clock "
                "offset scores far higher, or the views disagree (pose source / frames); "
                "inconclusive when the evidence is thin (few edges, textureless, static, no "
                "overlap) or a searched geometry scores somewhat higher.")
    body = table_html(table.select(list(COLUMNS)), "t-geometry", "geometry verdict per camera "
                      "(geometry.parquet)")
    return Section("geometry", "Geometry verdict", head + body)
