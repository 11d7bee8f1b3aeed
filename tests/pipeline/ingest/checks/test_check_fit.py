"""Checks that fit themselves to the stream: calibration, switching off, the reject cap."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.checks.check_fit import FitGate, allowance
from pipeline.ingest.recording import ingest_recording
from schemas.config import IngestConfig
from schemas.recording_index import CHECKS, read_index_table, table_path
from tests.pipeline.ingest.bagkit import Mission, write_mission


def _run(gate: FitGate, flags: list[bool]) -> list[tuple[int, bool]]:
    """Push messages 0..n-1 flagged as given; (message, rejected) in release order."""
    out = []
    for i, bad in enumerate(flags):
        out += gate.push(i, {"c": "implausible" if bad else None})
    out += gate.flush()
    return [(r.item, r.rejected_by is not None) for r in out]


def test_allowance_boundaries() -> None:
    assert allowance(0, 0.02) == 1 and allowance(99, 0.02) == 1
    assert allowance(100, 0.02) == 2 and allowance(149, 0.02) == 2 and allowance(150, 0.02) == 3
    assert allowance(10, 0.0) == 1


def test_a_check_that_flags_every_message_is_switched_off_and_rejects_nothing() -> None:
    gate = FitGate("/t", ("c",), calibration=10, max_share=0.02)
    got = _run(gate, [True] * 50)
    assert [i for i, _ in got] == list(range(50)) and not any(r for _, r in got)
    rec = gate.records["c"]
    assert (rec.state, rec.messages, rec.flagged, rec.rejected) == ("off", 10, 10, 0)
    assert gate.notes == [f"check c does not fit topic /t: it {rec.detail}; switched off for "
                          "this topic"]
    assert "10 of the first 10 messages" in rec.detail and "implausible" in rec.detail


def test_nothing_is_released_before_the_calibration_ends() -> None:
    gate = FitGate("/t", ("c",), calibration=5)
    assert all(gate.push(i, {"c": None}) == [] for i in range(4))
    assert [r.item for r in gate.push(4, {"c": None})] == [0, 1, 2, 3, 4]
    assert [r.item for r in gate.push(5, {"c": None})] == [5]


def test_one_damaged_message_in_the_calibration_is_rejected() -> None:
    gate = FitGate("/t", ("c",), calibration=10)
    got = _run(gate, [i == 3 for i in range(30)])
    assert [i for i, r in got if r] == [3] and gate.records["c"].state == "on"
    assert gate.notes == []


def test_two_flagged_in_the_calibration_switch_the_check_off() -> None:
    gate = FitGate("/t", ("c",), calibration=10)
    got = _run(gate, [i in (2, 5) for i in range(12)])
    assert not any(r for _, r in got) and gate.records["c"].state == "off"


def test_past_its_share_a_check_stops_rejecting_and_keeps_the_messages() -> None:
    flags = [False] * 100 + [True] * 20 + [False] * 10
    gate = FitGate("/t", ("c",), calibration=10, max_share=0.02)
    got = _run(gate, flags)
    rejected = [i for i, r in got if r]
    assert rejected == [100, 101]  # allowance(102) = 2
    rec = gate.records["c"]
    assert (rec.state, rec.rejected, rec.flagged, rec.messages) == ("capped", 2, 3, 103)
    assert len(gate.notes) == 1 and gate.notes[0].startswith("check c does not fit topic /t")


def test_a_short_stream_is_decided_at_its_end() -> None:
    gate = FitGate("/t", ("c",), calibration=10)
    got = _run(gate, [False, True, False])
    assert got == [(0, False), (1, True), (2, False)]


def test_an_inactive_check_is_not_counted() -> None:
    gate = FitGate("/t", ("a", "b"), calibration=2)
    gate.push(0, {"a": "x"})
    gate.push(1, {"a": "x"})
    assert gate.records["a"].state == "off" and not gate.active("a")
    assert gate.push(2, {"a": "x", "b": None})[0].rejected_by is None
    assert gate.records["a"].messages == 2 and gate.records["b"].messages == 1


@settings(max_examples=100, deadline=None)
@given(st.lists(st.booleans(), max_size=300), st.integers(1, 20),
       st.sampled_from([0.0, 0.01, 0.02, 0.1]))
def test_a_check_never_rejects_more_than_its_allowance(flags: list[bool], calibration: int,
                                                       share: float) -> None:
    gate = FitGate("/t", ("c",), calibration=calibration, max_share=share)
    got = _run(gate, flags)
    assert [i for i, _ in got] == list(range(len(flags)))  # every message, in order
    n_rejected = sum(r for _, r in got)
    assert n_rejected <= allowance(len(flags), share)
    assert all(flags[i] for i, r in got if r)  # only flagged messages are rejected


def _rings_out_of_order(tmp: Path) -> Path:
    """A mission whose ring field does not index elevation (another driver's numbering)."""
    return write_mission(tmp, Mission(seconds=2.0, points=300, ring_order="random"))


def test_a_ring_field_that_does_not_index_elevation_loses_no_sweep(tmp_path: Path) -> None:
    cfg = IngestConfig(cameras=["front"], out_height=28, out_width=42)
    res = ingest_recording(_rings_out_of_order(tmp_path / "m"), tmp_path / "o", cfg)
    assert "bad_pointcloud" not in res.rejects and res.sweeps == 20
    rows = read_index_table(table_path(res.index_dir, "checks"), CHECKS).to_pylist()
    ring = next(r for r in rows if r["check"] == "ring_elevation")
    assert ring["state"] == "off" and ring["rejected"] == 0 and ring["flagged"] >= 2
    assert {r["check"] for r in rows} >= {"point_limits", "rotation", "quat_norm", "pose_jump",
                                          "image_drift"}
    assert all(r["state"] == "on" for r in rows if r["check"] != "ring_elevation")
    told = [w for w in res.warnings if "ring_elevation does not fit topic" in w]
    assert len(told) == 1 and "/boxi/hesai/points_undistorted" in told[0]
    assert res.checks == rows


@pytest.mark.parametrize("share", [0.0, 0.5])
def test_the_share_is_a_config_key(share: float) -> None:
    cfg = IngestConfig.model_validate({"checks": {"max_reject_share": share}})
    assert cfg.checks.max_reject_share == share
    assert np.isclose(IngestConfig().checks.max_reject_share, 0.02)


def test_checks_are_told_by_the_manifest_the_stats_summary_and_the_report(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cli.app import app
    from dags.graph import STAGES
    from pipeline.analysis.report.sections import rejects
    from pipeline.run.service import RunRequest, run_stages
    from schemas.manifest import read_manifest
    from tests.dags.conftest import tiny_config, write_config

    mission = _rings_out_of_order(tmp_path / "rec" / "m")
    cfg = tiny_config(tmp_path / "out", [mission])
    cfg = cfg.model_copy(update={"ingest": cfg.ingest.model_copy(update={"cameras": ["front"]})})
    summaries = run_stages(cfg, STAGES, RunRequest(only=("ingest",))).summaries
    assert not any(s.failed for s in summaries)
    manifest = read_manifest(cfg.output_dir)
    assert manifest is not None
    (rows,) = manifest.checks.values()
    ring = [r for r in rows if r["check"] == "ring_elevation"]
    assert len(ring) == 1 and ring[0]["state"] == "off" and ring[0]["rejected"] == 0
    html = rejects(cfg.output_dir).body
    assert 't-checks' in html and "ring_elevation" in html
    config = write_config(tmp_path / "c.yaml", cfg.output_dir, [mission])
    out = CliRunner().invoke(app, ["--config", str(config), "stats", "summary", "rejects"])
    assert "ring_elevation" in out.output and "off" in out.output, out.output


def test_messages_of_checksummed_chunks_are_trusted(tmp_path: Path) -> None:
    """The synthetic bags' LZ4 chunks carry content checksums (as `rosbag record --lz4`
    writes them): their messages skip the checks unless checks.trust_checksums is off."""
    import lz4.frame

    from pipeline.ingest.sources.ros1_index import checksummed
    from pipeline.synth.api import synthesize
    from schemas.config import SynthConfig

    assert checksummed(lz4.frame.compress(b"x" * 100, content_checksum=True))
    assert not checksummed(lz4.frame.compress(b"x" * 100, content_checksum=False))
    assert not checksummed(b"\x00" * 16)
    res = synthesize(tmp_path, SynthConfig(seconds=0.5, image_width=96, image_height=64,
                                           points_per_sweep=512, cameras=["front"],
                                           depth_maps=False), "corridor", "m")  # fmt: skip
    rows = {}
    for trust in (True, False):
        cfg = IngestConfig.model_validate({"cameras": ["front"], "out_height": 28,
                                           "out_width": 42,
                                           "checks": {"trust_checksums": trust}})  # fmt: skip
        out = ingest_recording(res.mission_dir, tmp_path / f"o{trust}", cfg)
        assert out.rejects == {}
        rows[trust] = {(r["topic"], r["check"]): r for r in out.checks}
    sweep = ("/boxi/hesai/points_undistorted", "ring_elevation")
    assert rows[True][sweep]["trusted"] == res.sweeps and rows[True][sweep]["messages"] == 0
    assert rows[False][sweep]["trusted"] == 0 and rows[False][sweep]["messages"] == res.sweeps


def test_a_check_that_stops_fitting_mid_stream_is_capped_and_the_sweeps_kept(
        tmp_path: Path) -> None:
    """Rings index elevation in the first 10 sweeps, not after (a driver restarted with
    another numbering): the ring check passes its calibration, rejects one sweep (its
    allowance) and then stops rejecting; the other 9 are kept and the run says so."""
    cfg = IngestConfig(cameras=["front"], out_height=28, out_width=42)
    m = write_mission(tmp_path / "m", Mission(seconds=2.0, points=300,
                                              ring_order="random_from_10"))  # fmt: skip
    res = ingest_recording(m, tmp_path / "o", cfg)
    assert res.rejects == {"bad_pointcloud": 1} and res.sweeps == 19
    ring = next(r for r in res.checks if r["check"] == "ring_elevation")
    assert (ring["state"], ring["rejected"], ring["flagged"]) == ("capped", 1, 2)
    told = [w for w in res.warnings if "check ring_elevation does not fit topic" in w]
    assert len(told) == 1 and "the messages are kept" in told[0]
