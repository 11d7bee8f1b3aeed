"""Agreement is the test: one synthetic recording read from its bags and from its KITTI-360 copy.

What the copy carries whole agrees exactly or at micrometres: stamps (ns), sweep points (bit for
bit), calibration (T_base_sensor, K_out), the sweep each view selects and its Delta-tau, and the
camera pose at `image_00` frames. What the layout loses is checked as such: poses exist only at
`image_00`'s frames (10 Hz, the bags' odometry is 20 Hz), so the chain at a sweep stamp is
interpolated between frames. Given the bags' odometry sampled at those same frames, the copy's
LiDAR->camera chain is the bags' at micrometres: the geometry is the same, only the pose rate
differs. Views outside the span of `image_00`'s frames have no pose in the copy (odom_gap).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from packets.poses import compose, interpolate_poses, invert_T, lidar_to_camera
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.kitti360 import Kitti360Source
from pipeline.ingest.sources.sweep_reader import iter_sweeps
from pipeline.select.views import load_odometry, select_views
from schemas.config import SelectConfig
from schemas.recording_index import INDEX_TABLES, SELECTION, read_index_table, table_path
from tests.pipeline.ingest.sources.kitti360_kit import INGEST, bags_of, kitti_root

FORMATS = ("rosbag", "kitti360")
UM = 1e-6  # one micrometre (m); rotations compared at 1e-6 too (about 0.2 arcsec)


@pytest.fixture(scope="module")
def index(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Index folders (ingest + selection) of the 'clean' recording per format."""
    out = tmp_path_factory.mktemp("k360_agree")
    res = {"rosbag": ingest_recording(bags_of(tmp_path_factory), out / "bag", INGEST),
           "kitti360": Kitti360Source().ingest(kitti_root(tmp_path_factory), out / "k360",
                                               INGEST, None, "clean")}  # fmt: skip
    for r in res.values():
        select_views(r.index_dir, SelectConfig(), INGEST)
    return {f: r.index_dir for f, r in res.items()}


def _table(idx: Path, name: str) -> list[dict[str, Any]]:
    schema = SELECTION if name == "selection" else INDEX_TABLES[name]
    rows: list[dict[str, Any]] = read_index_table(table_path(idx, name), schema).to_pylist()
    return rows


def _T(row: dict[str, Any], key: str) -> np.ndarray:
    return np.asarray(row[key], dtype=np.float64).reshape(4, 4)


def test_stamps_points_and_calibration_agree(index: dict[str, Path],
                                             tmp_path_factory: pytest.TempPathFactory) -> None:
    bag, k = (index[f] for f in FORMATS)
    for name in ("images", "sweeps"):
        a, b = _table(bag, name), _table(k, name)
        assert [r["stamp_ns"] for r in a] == [r["stamp_ns"] for r in b], name  # to the ns
    sw_a, sw_b = _table(bag, "sweeps"), _table(k, "sweeps")
    for a, b in zip(sw_a, sw_b, strict=True):
        assert [a[c] for c in ("n_points", "n_valid", "n_nonfinite", "n_zero")] == [
            b[c] for c in ("n_points", "n_valid", "n_nonfinite", "n_zero")]
        assert a["t_last_ns"] - a["t_first_ns"] > 50_000_000  # per-point time in the bag
        assert b["t_first_ns"] == b["t_last_ns"] == b["stamp_ns"]  # none in KITTI-360
    pts_a = list(iter_sweeps(bags_of(tmp_path_factory), sw_a[:3]))
    pts_b = list(Kitti360Source().iter_sweeps(kitti_root(tmp_path_factory), sw_b[:3]))
    for a, b in zip(pts_a, pts_b, strict=True):
        assert a.xyz.tobytes() == b.xyz.tobytes() and a.intensity.tobytes() == b.intensity.tobytes()
    cal_a = {r["sensor"]: r for r in _table(bag, "calibration")}
    cal_b = {r["sensor"]: r for r in _table(k, "calibration")}
    for sensor in ("front", "left", "lidar"):
        assert np.abs(_T(cal_a[sensor], "T_base_sensor")
                      - _T(cal_b[sensor], "T_base_sensor")).max() < 1e-12  # fmt: skip
    for cam in ("front", "left"):
        np.testing.assert_allclose(cal_a[cam]["K_out"], cal_b[cam]["K_out"], rtol=1e-12)


def test_same_selection_and_front_pose(index: dict[str, Path]) -> None:
    bag, k = (_table(index[f], "selection") for f in FORMATS)
    assert len(bag) == len(k) == 46
    covered = _covered(index["kitti360"])
    compared = 0
    for a, b in zip(bag, k, strict=True):
        assert (a["camera"], a["frame"], a["sweep"], a["stamp_ns"]) == (
            b["camera"], b["frame"], b["sweep"], b["stamp_ns"])
        assert a["dtau_s"] == b["dtau_s"] and a["K_out"] == b["K_out"]
        if not (covered(a["stamp_ns"]) and covered(a["sweep_stamp_ns"])):
            assert b["reason"] in ("odom_gap", "dtau_exceeded")  # no pose there in the copy
            continue
        assert (a["status"], a["reason"]) == (b["status"], b["reason"])
        if a["camera"] == "front":  # image_00: a pose row at its own stamp
            assert np.abs(_T(a, "T_world_cam") - _T(b, "T_world_cam")).max() < UM
            compared += 1
    assert compared > 15


def _covered(idx: Path) -> Any:
    od = _table(idx, "odometry")
    lo, hi = od[0]["stamp_ns"], od[-1]["stamp_ns"]
    return lambda t: lo <= t <= hi


def test_chain_is_the_bags_at_the_same_pose_rate(index: dict[str, Path]) -> None:
    """The copy's T_cam_lidar equals the chain of the bags' own index with its odometry sampled
    at image_00's frames (what the layout keeps); against the full 20 Hz odometry it differs by
    the pose interpolation alone (bounded, not zero: the robot sways between frames)."""
    bag, k = (index[f] for f in FORMATS)
    odo = load_odometry(bag)
    frames0 = np.array([r["stamp_ns"] for r in _table(bag, "images") if r["camera"] == "front"])
    at0 = interpolate_poses(odo.stamps, odo.pos, odo.quat, frames0, 10**9)
    assert at0.ok.all()
    q0 = np.array([_quat(T) for T in at0.T])
    cal = {r["sensor"]: r for r in _table(bag, "calibration")}
    worst_um, worst_full = 0.0, 0.0
    rows = [(a, b) for a, b in zip(_table(bag, "selection"), _table(k, "selection"), strict=True)
            if b["status"] == "ok"]  # fmt: skip
    assert len(rows) > 25
    for a, b in rows:
        T = interpolate_poses(frames0, at0.T[:, :3, 3], q0,
                              np.array([b["stamp_ns"], b["sweep_stamp_ns"]]), 10**9).T
        want = lidar_to_camera(_T(cal[b["camera"]], "T_base_sensor"), T[0], T[1],
                               _T(cal["lidar"], "T_base_sensor"))  # fmt: skip
        worst_um = max(worst_um, float(np.abs(want - _T(b, "T_cam_lidar")).max()))
        diff = compose(invert_T(_T(a, "T_cam_lidar")), _T(b, "T_cam_lidar"))
        worst_full = max(worst_full, float(np.abs(diff[:3, 3]).max()))
    assert worst_um < UM
    assert worst_full < 0.01  # m: pose interpolation at 10 Hz instead of 20 Hz


def _quat(T: np.ndarray) -> np.ndarray:
    from packets.poses import rot_to_quat

    return np.asarray(rot_to_quat(T[:3, :3]))


def test_faulty_recording_gives_the_same_rejects(tmp_path_factory: pytest.TempPathFactory,
                                                 tmp_path: Path) -> None:
    """The bags' faults carry over: a corrupt JPEG is a frame without a file (missing_file),
    stamps repeated or out of order are refused in the folder and again in poses.txt (its
    frames take image_00's stamps), gaps and the empty sweep are the same rejects."""
    bag = ingest_recording(bags_of(tmp_path_factory, "faulty"), tmp_path / "bag", INGEST)
    k = Kitti360Source().ingest(kitti_root(tmp_path_factory, "faulty"), tmp_path / "k", INGEST,
                                None, "faulty")  # fmt: skip
    assert bag.images == k.images and bag.sweeps == k.sweeps and k.unaccounted == {}
    want = {("missing_file" if r == "corrupt_jpeg" else r): n for r, n in bag.rejects.items()}
    assert want["missing_file"] == 2 and want["duplicate_stamp"] == 1
    by_topic: dict[str, dict[str, int]] = {}
    for r in _table(k.index_dir, "rejects"):
        by_topic.setdefault(r["topic"], {}).setdefault(r["reason"], 0)
        by_topic[r["topic"]][r["reason"]] += 1
    sensors: dict[str, int] = {}
    for topic, counts in by_topic.items():
        for reason, n in counts.items():
            sensors[reason] = sensors.get(reason, 0) + (n if topic != "poses" else 0)
    assert sensors == want
    image00 = {r: n for r, n in by_topic["image_00"].items() if r != "missing_file"}
    assert by_topic["poses"] == image00  # the same untrusted stamps
    kinds = [[(r["n_nan"], r["n_posinf"], r["n_zero"]) for r in _table(x.index_dir, "sweeps")]
             for x in (bag, k)]  # fmt: skip
    assert kinds[0] == kinds[1] and sum(n > 0 for n, _, _ in kinds[0]) >= 1
