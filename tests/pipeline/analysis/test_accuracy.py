"""`m3gd accuracy` over a real output with ground truth, and select.time_offset_s against an
injected camera clock offset."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest

from bench.recording import Recording
from bench.tradeoffs import collect
from dags.graph import STAGES
from pipeline.analysis.accuracy import ViewTruth, cell_rows, rows_table, run_accuracy, summarize
from pipeline.analysis.query import query
from pipeline.run.service import run_stages
from pipeline.select.views import select_views
from pipeline.synth.api import synthesize
from schemas.config import M3GDConfig, SelectConfig, parse_config
from schemas.recording_index import SELECTION, read_index_table

OFFSET_S = 0.06
SYNTH = {"seconds": 2.0, "image_width": 240, "image_height": 160, "points_per_sweep": 4096,
         "cameras": ["front", "left"], "speed_mps": 1.0, "yaw_rate_max_rps": 1.0,
         "yaw_period_s": 4.0, "camera_clock_offset_s": OFFSET_S}


def _cfg(out: Path, mission: Path, **select: Any) -> M3GDConfig:
    return parse_config({
        "output_dir": str(out),
        "ingest": {"recordings": [str(mission)], "out_height": 112, "out_width": 168,
                   "cameras": ["front", "left"]},
        "select": {"time_offset_s": OFFSET_S, **select},
        "packets": {"mode": "geom_only"}, "encoders": {"image_channels": 588},
        "dag": {"retries": 0}, "clips": {"eval_clips_per_recording": 4}})


@pytest.fixture(scope="module")
def output(tmp_path_factory: pytest.TempPathFactory) -> M3GDConfig:
    base = tmp_path_factory.mktemp("accuracy")
    res = synthesize(base / "rec", parse_config({"synth": SYNTH}).synth, "corridor", "turning")
    cfg = _cfg(base / "out", res.mission_dir)
    run_stages(cfg, STAGES)
    return cfg


def _no_nan(name: str) -> None:
    raise AssertionError(f"{name} in strict JSON")


def test_accuracy_report_over_an_output(output: M3GDConfig) -> None:
    rep = run_accuracy(output)
    s = json.loads(rep.summary_path.read_text(), parse_constant=_no_nan)  # strict JSON
    assert s == json.loads(json.dumps(rep.summary))
    n = query(output.output_dir, "SELECT count(*) AS n FROM accuracy").to_pylist()[0]["n"]
    assert n == s["cells"] > 500
    assert s["views"] > 20 and s["select_time_offset_s"] == OFFSET_S
    assert s["depth_absrel_interior"] < 0.03  # packets land on the surfaces the camera sees
    assert s["depth_absrel_border"] > s["depth_absrel_interior"]
    assert 0.5 < s["max_abs_yaw_rate_rps"] < 1.5 and 0.8 < s["max_speed_mps"] < 1.2
    assert sum(b["n"] for b in s["by_abs_dtau_ms"].values()) == s["depth_n"]
    assert {p.name for p in rep.plots} == {"accuracy_vs_dtau.png", "accuracy_map.png"}


def test_time_offset_correction_restores_the_accuracy(output: M3GDConfig) -> None:
    idx = output.output_dir / "index" / "turning"
    rec = Recording(output, "turning", Path(output.ingest.recordings[0]), idx)
    fixed = collect([rec], 40, 0).pairs.absrel("base", "interior")
    dtau_fixed = read_index_table(idx / "selection.parquet", SELECTION)["dtau_s"].to_numpy()
    raw_sel = SelectConfig(time_offset_s=0.0)
    try:
        select_views(idx, raw_sel, output.ingest)
        raw = Recording(output.model_copy(update={"select": raw_sel}), rec.name, rec.mission, idx)
        wrong = collect([raw], 40, 0).pairs.absrel("base", "interior")
        dtau_raw = read_index_table(idx / "selection.parquet", SELECTION)["dtau_s"].to_numpy()
    finally:
        select_views(idx, output.select, output.ingest)
    same = np.abs(dtau_fixed - dtau_raw - OFFSET_S) < 1e-9  # views that kept their sweep
    assert same.mean() > 0.3
    assert wrong > 2 * fixed  # 6 cm and up to 0.06 rad of motion unaccounted for


def _view(dtau: float, speed: float, border: np.ndarray, ref: float) -> ViewTruth:
    from packets.accuracy import CellReference

    med = np.full(border.shape, ref)
    return ViewTruth("front", 0, 0, dtau, "ok", 0, np.eye(4), np.eye(3),
                     CellReference(med, np.zeros_like(med), border), speed, 0.0)


def test_summary_numbers_in_closed_form() -> None:
    """Plane at D = 4 m, LiDAR off by the travel v |Δτ| (no odometry chain): abs-rel = v|Δτ|/D,
    so the slope per 0.1 m of travel is 0.1 / D = 0.025; border cells carry an extra +10 %."""
    D, border = 4.0, np.zeros((2, 3), bool)
    border[0, 0] = True
    parts = []
    for frame, (dtau, v) in enumerate([(0.0, 1.0), (0.02, 1.0), (0.05, 2.0), (-0.15, 1.0)]):
        depth = np.full((2, 3), D + v * abs(dtau))
        depth[0, 0] = D * 1.1 + v * abs(dtau)
        view = _view(dtau, v, border, D)
        part = cell_rows("r", view, depth)
        part["frame"][:] = frame
        parts.append(part)
    t = rows_table(parts)
    s = summarize(t)
    travel = np.array([0.0, 0.02, 0.1, 0.15])
    assert s["depth_absrel_interior"] == pytest.approx(np.mean(travel) / D)
    assert s["depth_absrel_border"] == pytest.approx(np.mean(travel / D + 0.1))
    assert s["absrel_per_100ms_dtau_at_1mps"] == pytest.approx(0.1 / D)
    assert s["by_abs_dtau_ms"]["20-30"]["abs_rel"] == pytest.approx((5 * 0.005 + 0.105) / 6)
    assert s["by_abs_dtau_ms"]["100-200"]["n"] == 6
    assert isinstance(t, pa.Table) and t.num_rows == 24


def test_no_view_matching_the_ground_truth_gives_an_empty_table() -> None:
    """A recording none of whose views meets its ground truth: an empty table of the schema
    and a summary of zero cells (was an ArrowTypeError on the string columns)."""
    from schemas.tables import ACCURACY

    table = rows_table([])
    assert table.num_rows == 0 and table.schema == ACCURACY
    out = summarize(table)
    assert out["cells"] == 0 and out["views"] == 0 and np.isnan(out["depth_abs_rel"])
