"""Each LiDAR topic's point-time convention: decided on its first sweeps (or by the config),
recorded in the checks and sweeps tables, and used by every later read of a sweep."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.sweep_reader import load_sweep
from pipeline.synth.api import synthesize
from schemas.config import IngestConfig, SynthConfig
from schemas.recording_index import CHECKS, SWEEPS, read_index_table, table_path
from tests.pipeline.ingest.bagkit import Mission, write_mission

LIDAR = "/boxi/hesai/points_undistorted"


def _cfg(point_time: object = "auto") -> IngestConfig:
    return IngestConfig.model_validate({"cameras": ["front"], "out_height": 28, "out_width": 42,
                                        "topics": {"lidar_point_time": point_time}})


def _tables(idx: Path) -> tuple[list[dict], dict]:
    sweeps = read_index_table(table_path(idx, "sweeps"), SWEEPS).to_pylist()
    checks = read_index_table(table_path(idx, "checks"), CHECKS).to_pylist()
    (row,) = [c for c in checks if c["check"] == "point_time"]
    return sweeps, row


def test_auto_decides_on_evidence_and_records_it(tmp_path: Path) -> None:
    mission = write_mission(tmp_path / "in", Mission(seconds=1.5))
    res = ingest_recording(mission, tmp_path / "out", _cfg())
    sweeps, row = _tables(res.index_dir)
    assert row["state"] == "on" and row["topic"] == LIDAR and row["messages"] == 8
    assert row["detail"].startswith("auto: timestamp float64 s absolute; evidence: 8 sweeps")
    assert {(s["time_field"], s["time_unit"], s["time_reference"]) for s in sweeps} == {
        ("timestamp", "s", "absolute")}
    spans = [s["t_last_ns"] - s["t_first_ns"] for s in sweeps]
    assert min(spans) > 80_000_000 and max(spans) <= 90_001_000  # bagkit: 0.09 s sweeps
    assert res.rejects == {} and res.sweeps == len(sweeps)
    # a later read decodes with the recorded convention
    sw = load_sweep(mission, sweeps[3])
    assert (int(sw.t_ns.min()), int(sw.t_ns.max())) == (sweeps[3]["t_first_ns"],
                                                        sweeps[3]["t_last_ns"])


def test_no_convention_fits_warns_once_and_points_take_the_header_stamp(tmp_path: Path) -> None:
    mission = write_mission(tmp_path / "in", Mission(seconds=1.5, zero_times=True))
    res = ingest_recording(mission, tmp_path / "out", _cfg())
    notes = [w for w in res.warnings if "no point-time convention fits" in w]
    assert len(notes) == 1 and LIDAR in notes[0]
    sweeps, row = _tables(res.index_dir)
    assert row["state"] == "off" and row["detail"].startswith("none: none (header stamps)")
    assert all(s["t_first_ns"] == s["t_last_ns"] == s["stamp_ns"] for s in sweeps)
    assert res.rejects == {} and len(sweeps) == 15  # not one sweep called damaged


@pytest.mark.parametrize(("setting", "detail"), [
    ({"field": "timestamp", "unit": "s", "reference": "absolute"},
     "config: timestamp float64 s absolute"),
    ("none", "none: none (header stamps)"),
])  # fmt: skip
def test_the_config_overrides_auto(tmp_path: Path, setting: object, detail: str) -> None:
    mission = write_mission(tmp_path / "in", Mission(seconds=1.0))
    res = ingest_recording(mission, tmp_path / "out", _cfg(setting))
    sweeps, row = _tables(res.index_dir)
    assert row["detail"].startswith(detail), row
    assert not [w for w in res.warnings if "point-time" in w or "point_time" in w]
    spans = {s["t_last_ns"] - s["t_first_ns"] > 0 for s in sweeps}
    assert spans == ({True} if setting != "none" else {False})


def test_a_config_the_evidence_contradicts_is_used_and_told(tmp_path: Path) -> None:
    mission = write_mission(tmp_path / "in", Mission(seconds=1.0))
    cfg = _cfg({"field": "timestamp", "unit": "ms", "reference": "absolute"})
    res = ingest_recording(mission, tmp_path / "out", cfg)
    assert [w for w in res.warnings if "the evidence does not fit it" in w]


def _synth_ingest(tmp: Path, variant: str) -> tuple[list[dict], dict, dict[str, int]]:
    cfg = SynthConfig(seconds=1.2, image_width=96, image_height=64, points_per_sweep=1024,
                      cameras=["front"], depth_maps=False, variant=variant)
    res = synthesize(tmp / "in", cfg, "corridor", variant)
    out = ingest_recording(res.mission_dir, tmp / "out",
                           IngestConfig.model_validate({"cameras": ["front"], "out_height": 56,
                                                        "out_width": 84,
                                                        "checks": {"trust_checksums": False}}))
    sweeps, row = _tables(out.index_dir)
    return sweeps, row, out.rejects


def test_livox_float64_absolute_ns_is_read_not_rejected(tmp_path: Path) -> None:
    sweeps, row, rejects = _synth_ingest(tmp_path, "livox")
    assert row["detail"].startswith("auto: timestamp float64 ns absolute"), row
    assert rejects == {} and len(sweeps) == 12
    spans = np.array([s["t_last_ns"] - s["t_first_ns"] for s in sweeps])
    assert (spans > 90_000_000).all() and (spans < 100_000_000).all()


def test_uint32_microseconds_span_a_100_ms_sweep(tmp_path: Path) -> None:
    sweeps, row, rejects = _synth_ingest(tmp_path, "time_uint32_us_first_point")
    assert row["detail"].startswith("auto: t uint32 us first_point"), row
    assert rejects == {}
    spans = np.array([s["t_last_ns"] - s["t_first_ns"] for s in sweeps])
    assert (spans > 90_000_000).all() and (spans < 100_000_000).all()  # not 0.1 ms


def test_a_header_stamped_at_the_sweep_end_reads_negative_offsets(tmp_path: Path) -> None:
    sweeps, row, rejects = _synth_ingest(tmp_path, "time_int64_ns_header")
    assert row["detail"].startswith("auto: time int64 ns header"), row
    assert rejects == {}
    assert all(s["t_last_ns"] == s["stamp_ns"] > s["t_first_ns"] for s in sweeps)
