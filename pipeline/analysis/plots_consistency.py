"""The report plot of `m3gd align --consistency` (stats/reprojection_consistency.parquet): reads
the table and, for synthetic recordings, the injected clock offset and camera rotation from
their ground truth, and draws `plots.plot_reprojection_consistency`."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq

from pipeline.analysis.plot_data import consistency_data
from pipeline.analysis.plots import plot_reprojection_consistency
from pipeline.synth.groundtruth import GT_DIR
from schemas.layout import OutputLayout

CONSISTENCY_TABLE = "reprojection_consistency.parquet"
"""The table `m3gd align --consistency` writes under stats/."""
PLOT_NAME = "reprojection_consistency.png"


def injected_truth(scene_json: Path) -> dict[str, float]:
    """The camera faults a synthetic recording was made with (`pipeline.synth.api`
    scene.json): offset_ms (camera clock minus LiDAR clock) and roll / pitch / yaw deg of
    the mounting error (0 when the file names none: the recording was made without one)."""
    scene = json.loads(scene_json.read_text())
    roll, pitch, yaw = scene.get("camera_extrinsic_error_deg", (0.0, 0.0, 0.0))
    return {"offset_ms": float(scene.get("camera_clock_offset_ns", 0)) * 1e-6,
            "roll_deg": float(roll), "pitch_deg": float(pitch), "yaw_deg": float(yaw)}


def truths(output_dir: Path, recordings: list[str]) -> dict[str, dict[str, float]]:
    """Injected values of the recordings synthesized under `<output_dir>/recordings/` (where
    `m3gd run` puts them when none is configured); others are unknown (left out)."""
    out = {}
    for rec in recordings:
        scene = OutputLayout(output_dir).recordings / rec / GT_DIR / "scene.json"
        if scene.is_file():
            out[rec] = injected_truth(scene)
    return out


def consistency_plot(output_dir: Path, plots_dir: Path) -> Path | None:
    """Draw `plots_dir/reprojection_consistency.png` from the output's consistency table;
    None (and a stale plot of an earlier table removed) when the table is absent or empty."""
    path = OutputLayout(output_dir).stats / CONSISTENCY_TABLE
    out = plots_dir / PLOT_NAME
    table = pq.read_table(path) if path.is_file() else None
    if table is None or table.num_rows == 0:
        out.unlink(missing_ok=True)
        return None
    recs = sorted(set(table["recording"].to_pylist()))
    return plot_reprojection_consistency(consistency_data(table, truths(output_dir, recs)), out)
