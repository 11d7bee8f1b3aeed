"""The report plot of `m3gd align --consistency`: its numbers (read by column name, injected
values from the table or the recordings' ground truth), the figure, and the report including
it exactly when the table exists."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipeline.analysis.plot_data import consistency_data
from pipeline.analysis.plots_consistency import PLOT_NAME, consistency_plot, injected_truth
from pipeline.analysis.report.build import build_report
from schemas.errors import DataError
from schemas.tables import REPROJECTION_CONSISTENCY, write_table


def _rows(recs: tuple[str, ...] = ("synth-a", "real-b")) -> list[dict[str, object]]:
    return [{"recording": r, "camera": "front", "pairs": 24, "points": 300,
             "offset_ms": 30.5 + i, "roll_deg": 0.1, "pitch_deg": 0.4 - i, "yaw_deg": -0.3,
             "rotation_deg": 0.5, "rotation_method": "lidar_edges", "edge_views": 8,
             "edge_points": 900, "edge_score_before": 0.2, "edge_score_after": 0.3,
             "error_before": 180.0, "error_after": 60.0 + i}
            for i, r in enumerate(recs)]


def _scene(where: Path, offset_ns: int, rot: list[float] | None) -> Path:
    where.mkdir(parents=True, exist_ok=True)
    scene = {"camera_clock_offset_ns": offset_ns,
             **({"camera_extrinsic_error_deg": rot} if rot is not None else {})}
    (where / "scene.json").write_text(json.dumps(scene))
    return where / "scene.json"


def test_injected_truth_reads_the_scene_and_defaults_to_no_mounting_error(tmp_path: Path
                                                                           ) -> None:
    assert injected_truth(_scene(tmp_path / "a", 30_000_000, [0.4, 0.0, -0.3])) == {
        "offset_ms": 30.0, "roll_deg": 0.4, "pitch_deg": 0.0, "yaw_deg": -0.3}
    assert injected_truth(_scene(tmp_path / "b", 0, None)) == {
        "offset_ms": 0.0, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0}


def test_data_fills_injected_values_where_known_and_nan_elsewhere() -> None:
    d = consistency_data(pa.Table.from_pylist(_rows()), {"synth-a": {
        "offset_ms": 30.0, "roll_deg": 0.4, "pitch_deg": 0.0, "yaw_deg": -0.3}})
    assert d["labels"] == ["synth-a/front", "real-b/front"]
    np.testing.assert_array_equal(d["offset_ms"], [30.5, 31.5])
    np.testing.assert_array_equal(d["after"], [60.0, 61.0])
    assert d["injected_offset_ms"][0] == 30.0 and np.isnan(d["injected_offset_ms"][1])
    np.testing.assert_array_equal(d["injected_rotation_deg"][0], [0.4, 0.0, -0.3])
    assert np.isnan(d["injected_rotation_deg"][1]).all()
    np.testing.assert_array_equal(d["rotation_deg"][1], [0.1, -0.6, -0.3])


def test_data_reads_columns_by_name_whatever_else_the_table_holds() -> None:
    """Injected columns in the table win over the ground truth; a table without rotation
    columns still plots; a missing error column is named."""
    rows = [{"error_after": 2.0, "camera": "left", "recording": "r", "error_before": 5.0,
             "injected_offset_ms": 12.0, "true_yaw_deg": 0.7, "extra": "x"}]
    d = consistency_data(pa.Table.from_pylist(rows), {"r": {"offset_ms": 99.0, "yaw_deg": 9.0}})
    assert d["injected_offset_ms"][0] == 12.0 and d["injected_rotation_deg"][0, 2] == 0.7
    assert np.isnan(d["offset_ms"]).all() and np.isnan(d["rotation_deg"]).all()
    with pytest.raises(DataError, match="error_after"):
        consistency_data([{"recording": "r", "camera": "c", "error_before": 1.0}])


def _output(tmp_path: Path, with_table: bool) -> Path:
    out = tmp_path / "out"
    (out / "stats").mkdir(parents=True)
    if with_table:
        write_table(pa.Table.from_pylist(_rows(), schema=REPROJECTION_CONSISTENCY),
                    REPROJECTION_CONSISTENCY, out / "stats" / "reprojection_consistency.parquet")
        _scene(out / "recordings" / "synth-a" / "groundtruth", 30_000_000, [0.0, 0.5, -0.3])
    return out


def test_the_plot_is_drawn_from_the_table(tmp_path: Path) -> None:
    out = _output(tmp_path, with_table=True)
    path = consistency_plot(out, out / "plots")
    assert path == out / "plots" / PLOT_NAME and path.stat().st_size > 10_000
    import shutil

    shutil.rmtree(out / "recordings")  # nothing injected known: recovered values per camera
    again = consistency_plot(out, out / "plots")
    assert again is not None and again.stat().st_size > 10_000


def test_report_includes_the_plot_when_the_table_exists(tmp_path: Path) -> None:
    out = _output(tmp_path, with_table=True)
    build_report(out, plots=True)
    html = (out / "report.html").read_text()
    assert 'data-file="reprojection_consistency"' in html
    assert "Reprojection consistency per recording/camera" in html


def test_report_omits_it_cleanly_without_the_table(tmp_path: Path) -> None:
    out = _output(tmp_path, with_table=False)
    (out / "plots").mkdir()
    (out / "plots" / PLOT_NAME).write_bytes(b"stale")  # from an earlier table, since removed
    build_report(out, plots=True)
    html = (out / "report.html").read_text()
    assert "reprojection_consistency" not in html and "Reprojection consistency" not in html
    assert not (out / "plots" / PLOT_NAME).exists()
    empty = pa.Table.from_pylist([], schema=REPROJECTION_CONSISTENCY)
    write_table(empty, REPROJECTION_CONSISTENCY, out / "stats" / "reprojection_consistency.parquet")
    assert consistency_plot(out, out / "plots") is None
