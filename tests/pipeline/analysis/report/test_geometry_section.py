"""The report's geometry section: a note without verdicts; with them, one row per camera and
the count of failed cameras."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa

from pipeline.analysis.report.geometry_section import geometry
from schemas.recording_index import GEOMETRY, write_index_table


def _row(camera: str, verdict: str) -> dict[str, object]:
    return {"camera": camera, "verdict": verdict, "reason": f"why {camera}", "cause": "",
            "accepted": False, "views": 24, "edge_points": 900, "score": 0.3,
            "null_mean": 0.01, "null_std": 0.02, "z": 14.5, "p_value": 0.0005, "wins": 1.0,
            "best_score": 0.2, "best_moved": "clock offset (+50 ms)"}


def test_no_verdict_is_a_note(tmp_path: Path) -> None:
    section = geometry(tmp_path)
    assert section.id == "geometry" and "the geometry stage has not run" in section.body


def test_one_row_per_camera_and_the_failed_count(tmp_path: Path) -> None:
    rows = [_row("front", "ok"), _row("left", "failed")]
    write_index_table(pa.Table.from_pylist(rows, schema=GEOMETRY), GEOMETRY,
                      tmp_path / "index" / "rec_a" / "geometry.parquet")
    body = geometry(tmp_path).body
    assert "2 camera(s); 1 failed" in body and 'id="t-geometry"' in body
    assert body.count("<tr>") == 3 and "why left" in body and "rec_a" in body
