"""`m3gd align --consistency` on tiny synthetic recordings with an injected camera clock offset
and an injected extrinsic (mounting) rotation: both are recovered (offset within 5 ms, rotation
within 0.2 deg), the table is written and read back; with nothing injected the rotation is ~0,
and another seed and rotation are recovered too (slow); the pairing and grid rules on their
own."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.analysis.align_consistency import (
    ConsistencyResult,
    SweepGrid,
    pair_indices,
    run_consistency,
    summary_lines,
    write_consistency,
)
from pipeline.synth.streams import mounting_error
from schemas.config import SynthConfig
from schemas.errors import DataError
from schemas.tables import REPROJECTION_CONSISTENCY, read_table

OFFSET_S = 0.03
ROT_DEG = (0.0, 0.5, -0.3)  # roll, pitch, yaw


def consistency_of(base: Path, offset_s: float, rot_deg: tuple[float, float, float],
                   seed: int = 0, declared_offset_s: float = 0.0) -> tuple[Path, ConsistencyResult]:
    """A 3 s front-camera recording (turning, brisk; the default 32 x 512 LiDAR) with an
    injected clock offset and mounting rotation, run through ingest, select and packets (with
    `select.time_offset_s` = `declared_offset_s`), and its consistency check."""
    from dags.graph import STAGES
    from pipeline.run.service import run_stages
    from pipeline.synth.api import synthesize
    from tests.dags.conftest import tiny_config

    synthesize(base / "rec", SynthConfig(
        seconds=3.0, image_width=192, image_height=128, seed=seed,
        cameras=["front"], camera_clock_offset_s=offset_s, camera_extrinsic_error_deg=rot_deg,
        yaw_rate_max_rps=1.5, yaw_period_s=2.0, speed_mps=2.0), "corridor", mission="m")
    cfg = tiny_config(base / "out", [base / "rec" / "m"])
    cfg = cfg.model_copy(update={"select": cfg.select.model_copy(
        update={"time_offset_s": declared_offset_s})})
    stages = [s for s in STAGES if s.name in ("synth", "ingest", "select", "packets")]
    assert not any(s.failed for s in run_stages(cfg, stages).summaries)
    return cfg.output_dir, run_consistency(cfg, max_pairs=16)


def rotation_error_deg(row: dict[str, object], rot_deg: tuple[float, float, float]) -> float:
    """Angle (deg) between the recovered rotation of a table row and the injected one."""
    got = Rotation.from_rotvec(np.radians([row["pitch_deg"], row["yaw_deg"], row["roll_deg"]]))
    want = Rotation.from_matrix(mounting_error(rot_deg)[:3, :3])
    return float(np.degrees((got.inv() * want).magnitude()))


@pytest.fixture(scope="module")
def result(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ConsistencyResult]:
    """The injected case (OFFSET_S, ROT_DEG)."""
    return consistency_of(tmp_path_factory.mktemp("consistency"), OFFSET_S, ROT_DEG)


def test_recovers_an_injected_clock_offset_and_writes_the_table(
        result: tuple[Path, ConsistencyResult]) -> None:
    out, res = result
    (row,) = res.table.to_pylist()
    assert (row["recording"], row["camera"]) == ("m", "front") and row["pairs"] >= 8
    assert abs(row["offset_ms"] - OFFSET_S * 1e3) < 5.0, row
    assert row["error_after"] < row["error_before"]
    back = read_table(write_consistency(out, res.table), REPROJECTION_CONSISTENCY)
    assert back.to_pylist() == res.table.to_pylist()
    assert "m/front" in summary_lines(res)[1]


def test_recovers_an_injected_extrinsic_rotation_within_0_2_deg(
        result: tuple[Path, ConsistencyResult]) -> None:
    (row,) = result[1].table.to_pylist()
    assert row["rotation_method"] == "lidar_edges" and row["edge_views"] >= 10, row
    assert rotation_error_deg(row, ROT_DEG) < 0.2, row
    assert row["edge_score_after"] > row["edge_score_before"]


@pytest.mark.slow
@pytest.mark.parametrize(("offset_s", "rot_deg", "seed"), [
    (0.0, (0.0, 0.0, 0.0), 0),  # nothing injected: no bias
    (-0.02, (0.7, -1.0, 0.3), 3),  # another seed and sign (0.24 deg before the cubic track)
    (0.005, (0.89, -0.28, 0.57), 1),  # drawn at random: rotation per axis in +-1 deg,
    (0.011, (0.95, -0.55, 0.61), 4),  # offset in +-30 ms (measured 0.11, 0.17, 0.05 deg)
    (0.004, (-0.06, -0.94, 0.79), 6),
    pytest.param(-0.008, (-0.41, 0.85, 0.74), 2, marks=pytest.mark.xfail(
        strict=True, reason="measured 2026-11-27: 0.26 deg (roll -0.15 for -0.41): the score "
        "itself peaks there on this recording (docs/benchmarks_packets.md)")),  # drawn too
])
def test_recovers_other_rotations_and_nothing_when_none_is_injected(
        tmp_path: Path, offset_s: float, rot_deg: tuple[float, float, float],
        seed: int) -> None:
    (row,) = consistency_of(tmp_path, offset_s, rot_deg, seed)[1].table.to_pylist()
    assert abs(row["offset_ms"] - offset_s * 1e3) < 5.0, row
    assert rotation_error_deg(row, rot_deg) < 0.2, row


def test_mounting_error_is_exactly_the_identity_at_zero_and_turns_about_optical_axes() -> None:
    T = np.arange(16.0).reshape(4, 4) / 7
    assert np.array_equal(T @ mounting_error((0.0, 0.0, 0.0)), T)  # default bags unchanged
    pitch = mounting_error((0.0, 1.0, 0.0))[:3, :3]  # about x (right): z forward tips in y
    assert np.isclose(pitch[0, 0], 1.0) and pitch[1, 2] < 0
    roll = mounting_error((2.0, 0.0, 0.0))[:3, :3]  # about z (forward)
    assert np.isclose(roll[2, 2], 1.0)
    assert np.isclose(np.degrees(np.arctan2(roll[1, 0], roll[0, 0])), 2.0)


def test_pairs_are_spread_evenly_and_capped() -> None:
    assert pair_indices(4, (1, 2), 10) == [(0, 1), (0, 2), (1, 2), (1, 3), (2, 3)]
    capped = pair_indices(10, (2, 4), 4)
    assert len(capped) == 4 and capped[0] == (0, 2) and capped[-1] == (7, 9)
    assert pair_indices(2, (2,), 5) == []


def test_sweep_grid_is_symmetric_and_refuses_degenerate_steps() -> None:
    g = SweepGrid(max_offset_ms=10, step_ms=5, max_rotation_deg=0.2, step_deg=0.1)
    np.testing.assert_allclose(g.offsets_s(), [-0.01, -0.005, 0, 0.005, 0.01])
    np.testing.assert_allclose(np.degrees(g.angles_rad()), [-0.2, -0.1, 0, 0.1, 0.2])
    for bad in (SweepGrid(step_ms=0), SweepGrid(max_rotation_deg=0.05), SweepGrid(rounds=0)):
        with pytest.raises(DataError, match="sweep grid"):
            bad.check()


def test_config_refuses_a_large_mounting_error() -> None:
    with pytest.raises(ValueError, match="camera_extrinsic_error_deg"):
        SynthConfig(camera_extrinsic_error_deg=(0.0, 11.0, 0.0))
