"""The proof reads every registered source (`RecordingSource.proof_data`): the dense corridor
in the Hugging Face and the KITTI-360 layouts is proven as the bags are; a LiDAR extrinsic
turned (KITTI-360 10 degrees, HF 20 degrees) is not; what a source cannot give is said in one
line; `--json` stays JSON, each LiDAR's point-time proof beside its convention."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from cli.app import app
from pipeline.inspect.prove import DISAGREES, PROVEN, UNPROVEN, prove
from pipeline.inspect.prove_read import VIEWS
from pipeline.inspect.prove_source import read_proof_data
from pipeline.inspect.recording import inspect_recording
from tests.pipeline.inspect.prove_sources_kit import hf_mission, kitti_root

RIG = ("pose", "lidar")


def test_hf_layout_is_read_and_proven(tmp_path_factory: pytest.TempPathFactory) -> None:
    ins = inspect_recording(hf_mission(tmp_path_factory))
    data = read_proof_data(ins, ["hesai_points_undistorted"])
    assert len(data.sweeps["hesai_points_undistorted"]) == VIEWS
    assert all(v is not None and v.grey.shape[1] <= 192 for v in data.images["hdr_front"])
    assert len(data.odometry["anymal_state_odometry"]) > 10 and not data.problems
    report, fixed = prove(ins, data)
    for what in (*RIG, "camera hdr_front"):
        proof = report.of(what)
        assert proof is not None and proof.status == PROVEN, proof
        assert proof.candidates[0].z is not None and proof.candidates[0].z > 4
    time = report.of("point_time hesai_points_undistorted")
    assert time is not None and time.status == UNPROVEN and "no per-point time" in time.note
    assert fixed.decisions == ins.decisions


def test_kitti360_layout_rig_is_proven(tmp_path_factory: pytest.TempPathFactory) -> None:
    ins = inspect_recording(kitti_root(tmp_path_factory))
    assert not ins.decisions  # the layout leaves no choice: the proof judges its one rig
    report, fixed = prove(ins)
    for what in (*RIG, "camera image_00"):
        proof = report.of(what)
        assert proof is not None and (proof.status, len(proof.candidates)) == (PROVEN, 1), proof
        assert proof.candidates[0].z is not None and proof.candidates[0].z > 4
    assert fixed == ins and not report.problems


def test_kitti360_calibration_turned_10_degrees_disagrees(
        tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:  # fmt: skip
    root = tmp_path / "k360"
    shutil.copytree(kitti_root(tmp_path_factory), root)
    f = root / "calibration" / "calib_cam_to_velo.txt"
    T = np.eye(4)
    T[:3] = np.array(f.read_text().split(), float).reshape(3, 4)
    R = np.eye(4)
    R[:3, :3] = Rotation.from_euler("z", 10, degrees=True).as_matrix()
    f.write_text(" ".join(f"{v:.12g}" for v in (R @ T)[:3].ravel()) + "\n")
    report, _ = prove(inspect_recording(root))
    assert {p.what for p in report.disagrees} == {*RIG, "camera image_00"}


def test_hf_lidar_extrinsic_turned_20_degrees_disagrees(
        tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:  # fmt: skip
    root = tmp_path / "hf"
    shutil.copytree(hf_mission(tmp_path_factory), root)
    attrs = root / "data" / "tf" / ".zattrs"
    meta = json.loads(attrs.read_text())
    entry = meta["tf"]["hesai_lidar"]["rotation"]  # the LiDAR turned 20 deg about its z
    q = Rotation.from_quat([entry[k] for k in "xyzw"]) * Rotation.from_euler("z", 20,
                                                                               degrees=True)
    meta["tf"]["hesai_lidar"]["rotation"] = dict(zip("xyzw", q.as_quat().tolist(), strict=True))
    attrs.write_text(json.dumps(meta))
    report, _ = prove(inspect_recording(root))
    assert {p.what for p in report.disagrees} == {*RIG, "camera hdr_front"}


def test_a_camera_the_source_cannot_give_is_said_in_one_line(
        tmp_path_factory: pytest.TempPathFactory, tmp_path: Path) -> None:  # fmt: skip
    root = tmp_path / "k360"
    shutil.copytree(kitti_root(tmp_path_factory), root)
    persp = root / "calibration" / "perspective.txt"
    persp.write_text("".join(line + "\n" for line in persp.read_text().splitlines()
                             if not line.startswith("P_rect_00")))  # fmt: skip
    ins = inspect_recording(root)
    report, _ = prove(ins)
    assert any("image_00" in p and "perspective.txt" in p for p in report.problems)
    assert not report.disagrees and report.of("camera image_00") is None


@pytest.mark.parametrize("layout", ["hf", "kitti360"])
def test_inspect_json_is_valid_with_the_proof(tmp_path_factory: pytest.TempPathFactory,
                                              tmp_path: Path, layout: str) -> None:  # fmt: skip
    rec = hf_mission(tmp_path_factory) if layout == "hf" else kitti_root(tmp_path_factory)
    cfg = tmp_path / "c.yaml"
    out = CliRunner().invoke(app, ["inspect", str(rec), "--write-config", str(cfg), "--json"])
    assert out.exit_code == 0, out.output
    proof = json.loads(out.output)["proof"]
    assert {d["status"] for d in proof["decisions"] if d["what"] in RIG} == {PROVEN}
    assert "# decided pose:" in cfg.read_text() and "geometry: proven" in cfg.read_text()
    assert DISAGREES not in {d["status"] for d in proof["decisions"]}
    beside = json.loads(out.output)["clouds"][0]["convention"]["geometry"]
    assert beside["status"] == UNPROVEN and "no per-point time" in beside["line"]


def test_a_source_without_the_proofs_reader_says_so(
        tmp_path_factory: pytest.TempPathFactory,
        monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    import pipeline.inspect.prove_source as prove_source

    class Older:
        name = "older"

    monkeypatch.setattr(prove_source, "source_for", lambda _: Older())
    ins = inspect_recording(hf_mission(tmp_path_factory))
    report, fixed = prove(ins)
    assert report.problems == ("the older source cannot give the proof's views yet",)
    assert {p.status for p in report.proofs} == {UNPROVEN} and fixed.decisions == ins.decisions
