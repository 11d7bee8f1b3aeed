"""The geometry verdict on small synthetic recordings: good data is `ok` (never `failed`);
every fault of issue 47 (`pipeline.analysis.geometry_faults`) is never `ok`, a wrong pose
source failed by the views' disagreement, a 5 deg extrinsic rotation with its cause named;
textureless images and a static robot are `inconclusive` with the reason. Faults are injected
into the geometry the check reads (the recording's poses and calibration), so one recording
serves every case. Then the stage: its tables, checks rows, manifest entry and report lines;
a failed camera fails the item in one line naming it, and `geometry.accept` accepts it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from packets.geometry_verdict import FAILED, INCONCLUSIVE, OK
from pipeline.analysis import geometry_check as gc
from pipeline.analysis import geometry_views as gv
from pipeline.analysis.align_lidar import BodyTrack, body_track
from pipeline.analysis.geometry_faults import FAULTS
from pipeline.analysis.geometry_scoring import diagonal
from pipeline.run.service import RunOutcome
from pipeline.stages.common import index_path
from schemas.config import M3GDConfig, SynthConfig
from schemas.manifest import read_manifest
from schemas.recording_index import CHECKS, GEOMETRY, read_index_table, table_path

REC = "g"


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> M3GDConfig:
    """A 3 s corridor recording (front and left cameras, 16384 points a sweep: the demo's
    scan density) through ingest and select with the DAG tests' tiny config (the check reads
    the index, the images and `valid`, not the packets)."""
    from dags.graph import STAGES
    from pipeline.run.service import run_stages
    from pipeline.synth.api import synthesize
    from tests.dags.conftest import tiny_config

    base = tmp_path_factory.mktemp("geometry")
    synthesize(base / "rec", SynthConfig(seconds=3.0, image_width=192, image_height=128,
                                         points_per_sweep=16384, cameras=["front", "left"]),
               "corridor", mission=REC)
    cfg = tiny_config(base / "out", [base / "rec" / REC])
    stages = [s for s in STAGES if s.name in ("synth", "ingest", "select")]
    assert not any(s.failed for s in run_stages(cfg, stages).summaries)
    return cfg


Sets = tuple[dict[str, gv.CameraSet], gv.Poses]


@pytest.fixture(scope="module")
def sets(good: M3GDConfig) -> Sets:
    """The recording's camera sets by camera, and its poses."""
    body = gv.Poses.of(body_track(index_path(good, REC)))
    cams = gv.camera_sets(good, REC, Path(good.ingest.recordings[0]))
    return {cs.camera: cs for cs in cams}, body


def _turned(body: gv.Poses, camera: str, axis: str, deg: float) -> gv.Poses:
    """`body` with `camera`'s recorded extrinsic turned by `deg` about its optical `axis`."""
    T = dict(body.body.T_base)
    E = np.eye(4)
    E[:3, :3] = Rotation.from_euler(axis, deg, degrees=True).as_matrix()
    T[camera] = T[camera] @ E
    return gv.Poses.of(dataclasses.replace(body.body, T_base=T))


def test_a_dense_sweep_has_a_fine_resolution(sets: Sets) -> None:
    """16384 points a sweep (512 columns, rings 1 deg apart): fine enough to fail a camera."""
    cams, _ = sets
    for cs in cams.values():
        assert 0.5 < cs.resolution_deg < 1.5
        assert cs.resolution_deg >= np.degrees(cs.step_rad)


def test_good_recording_is_ok_with_its_score_far_above_the_null(sets: Sets) -> None:
    cams, body = sets
    for cam in ("front", "left"):
        res = gv.judge_camera(cams[cam], body)
        assert res.verdict.verdict == OK, (cam, res.verdict)
        assert res.test is not None and res.test.z >= 4 and res.test.wins >= 0.8
        assert res.best is not None and res.best.score < res.test.observed  # none beats it


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_every_fault_of_the_issue_is_never_ok_and_says_why(sets: Sets, fault: str) -> None:
    """Wrong pose frame, swapped cameras, 2 and 5 deg rotation, 10 cm translation, 50 ms clock
    offset, a reversed time convention: no camera ok, at least one failed; a camera not failed
    is inconclusive naming the better geometry the search found."""
    cams, body = FAULTS[fault](*sets)
    verdicts = {cam: gv.judge_camera(cs, body).verdict for cam, cs in cams.items()}
    assert all(v.verdict != OK for v in verdicts.values()), verdicts
    assert any(v.verdict == FAILED for v in verdicts.values()), verdicts
    assert all(v.cause and v.reason for v in verdicts.values()), verdicts


def test_a_wrong_pose_source_that_leaves_own_scores_high_is_failed_across_views(
        sets: Sets) -> None:
    """The wheel's track moves the LiDAR and the camera alike: the front camera's own score
    stays far above the null (only the milliseconds between sweep and image see the odometry);
    its views read across each other fall to the null, and that fails it."""
    cams, body = FAULTS["wrong_pose_frame"](*sets)
    res = gv.judge_camera(cams["front"], body)
    assert res.test is not None and res.test.z >= 4 and res.cross is not None
    assert res.cross.z < 2 and res.cross.score < 0.5 * res.cross.own
    assert res.verdict.verdict == FAILED and "disagree" in res.verdict.reason
    assert res.verdict.cause.startswith("pose source")


def test_good_views_agree_across_views(sets: Sets) -> None:
    cams, body = sets
    for cs in cams.values():
        cross = gv.judge_camera(cs, body).cross
        assert cross is not None and not cross.problem and cross.pairs >= 8
        assert cross.score > 0.9 * cross.own and cross.z >= 4


def test_a_5_deg_extrinsic_rotation_fails_naming_the_rotation(sets: Sets) -> None:
    cams, body = sets
    res = gv.judge_camera(cams["front"], _turned(body, "front", "y", 5.0))
    assert res.verdict.verdict == FAILED, res.verdict
    assert "extrinsic rotation (yaw" in res.verdict.cause and res.best is not None


def test_swapped_cameras_are_never_ok(sets: Sets) -> None:
    """Each camera's images read with the other camera's extrinsic (topics swapped)."""
    cams, body = sets
    T = dict(body.body.T_base)
    T["front"], T["left"] = T["left"], T["front"]
    swapped = gv.Poses.of(dataclasses.replace(body.body, T_base=T))
    verdicts = {cam: gv.judge_camera(cams[cam], swapped).verdict for cam in cams}
    assert all(v.verdict != OK for v in verdicts.values()), verdicts
    assert any(v.verdict == FAILED for v in verdicts.values()), verdicts


def test_textureless_images_are_inconclusive_saying_so(sets: Sets) -> None:
    cams, body = sets
    rng = np.random.default_rng(0)
    cs = cams["front"]
    flat = [dataclasses.replace(v, grey=np.full_like(v.grey, 128.0)
                                + rng.normal(0, 0.3, v.grey.shape)) for v in cs.views]
    assert all(gv.mean_gradient(v.grey) < gv.FLAT_GRADIENT for v in flat)
    # the check leaves flat views out where it reads them: rebuild the set as camera_sets does
    kept = [v for v in flat if gv.mean_gradient(v.grey) >= gv.FLAT_GRADIENT]
    res = gv.judge_camera(dataclasses.replace(cs, views=kept, flat=len(flat)), body)
    assert res.verdict.verdict == INCONCLUSIVE and "textureless" in res.verdict.reason


def test_a_static_robot_is_inconclusive_saying_the_views_are_alike(sets: Sets) -> None:
    """Every view sees the same image and sweep (the robot stood still)."""
    cams, body = sets
    cs = cams["front"]
    still = [dataclasses.replace(v, edges=cs.views[0].edges, T_odom_lidar=cs.views[0].T_odom_lidar,
                                 grey=cs.views[0].grey, image_ns=cs.views[0].image_ns)
             for v in cs.views]
    res = gv.judge_camera(dataclasses.replace(cs, views=still), body)
    assert res.verdict.verdict == INCONCLUSIVE and "alike" in res.verdict.reason


def test_score_matrix_diagonal_matches_the_full_matrix(sets: Sets) -> None:
    cams, body = sets
    views = [v for v in gv.edge_views(cams["front"], body) if len(v.points)][:6]
    maps = np.stack([gv.edge_map(v.grey, 1.0) for v in views], axis=2)
    S = gv.score_matrix(views, maps)
    np.testing.assert_allclose(np.diag(S), diagonal(views, maps), rtol=1e-12)
    from packets.edges import alignment_score

    assert S[1, 3] == pytest.approx(alignment_score([views[1]], [maps[:, :, 3]], np.zeros(3)))


def test_null_pairs_exclude_near_and_alike_views() -> None:
    rng = np.random.default_rng(0)
    maps = rng.normal(size=(8, 8, 4, 2))
    maps[:, :, 3] = maps[:, :, 0]  # view 3 sees what view 0 sees
    allowed = gv.null_pairs(maps)
    assert not allowed[0, 1] and not allowed[0, 0] and allowed[0, 2]
    assert not allowed[0, 3] and not allowed[3, 0] and allowed[1, 3]


def _run_geometry(cfg: M3GDConfig) -> RunOutcome:
    """Only the geometry stage of the graph (redone), over the recording's index and images."""
    from dags.graph import STAGES
    from pipeline.run.service import RunRequest, run_stages

    return run_stages(cfg, STAGES, RunRequest(only=("geometry",), force=("geometry",)))


def test_the_stage_records_its_verdicts_in_tables_checks_and_manifest(good: M3GDConfig) -> None:
    assert not any(s.failed for s in _run_geometry(good).summaries)
    idx = index_path(good, REC)
    rows = read_index_table(table_path(idx, "geometry"), GEOMETRY).to_pylist()
    assert {r["camera"]: r["verdict"] for r in rows} == {"front": OK, "left": OK}
    checks = [r for r in read_index_table(table_path(idx, "checks"), CHECKS).to_pylist()
              if r["check"] == "geometry"]
    assert {r["state"] for r in checks} == {OK} and len(checks) == 2
    assert checks[0]["topic"] == good.ingest.topics.image_topic(checks[0]["topic"].split("/")[3])
    manifest = read_manifest(good.output_dir)
    assert manifest is not None
    assert [r["check"] for r in manifest.checks[REC]].count("geometry") == 2
    entry = manifest.geometry()[REC]
    assert {v["state"] for v in entry.values()} == {OK} and len(entry) == 2
    assert all("cross-view score" in v["detail"] for v in entry.values())
    lines = gc.verdict_lines(good.output_dir)
    assert len(lines) == 2 and lines[0].startswith(f"geometry {REC}/front: ok: LiDAR-edge score")


def test_a_failed_camera_fails_the_item_in_one_line_unless_accepted(
        good: M3GDConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    real = gv.body_track

    def turned(idx: Path) -> BodyTrack:
        return _turned(gv.Poses.of(real(idx)), "front", "y", 5.0).body

    monkeypatch.setattr(gc, "body_track", turned)
    (summary,) = _run_geometry(good).summaries
    (line,) = summary.failed.values()
    assert line.startswith(f"GeometryFailed: geometry failed in recording {REC}: camera front:")
    assert "extrinsic rotation (yaw" in line and "--accept-geometry front" in line
    assert "\n" not in line and "camera left" not in line
    rows = read_index_table(table_path(index_path(good, REC), "geometry"), GEOMETRY).to_pylist()
    assert [r["verdict"] for r in rows] == [FAILED, OK] and not rows[0]["accepted"]
    manifest = read_manifest(good.output_dir)  # the failed verdict is in the manifest too
    assert manifest is not None
    assert sorted(v["state"] for v in manifest.geometry()[REC].values()) == [FAILED, OK]
    accepted = good.model_copy(update={"geometry": good.geometry.model_copy(
        update={"accept": [f"{REC}/front"]})})
    (summary,) = _run_geometry(accepted).summaries
    assert not summary.failed
    rows = read_index_table(table_path(index_path(good, REC), "geometry"), GEOMETRY).to_pylist()
    assert rows[0]["accepted"] and rows[0]["verdict"] == FAILED
    assert any("accepted" in line for line in gc.verdict_lines(good.output_dir))


def test_disabled_plans_nothing(good: M3GDConfig) -> None:
    off = good.model_copy(update={"geometry": good.geometry.model_copy(
        update={"enabled": False})})
    assert gc.plan_geometry(off) == [] and len(gc.plan_geometry(good)) == 1


@pytest.mark.slow
def test_the_command_names_a_failed_camera_and_exits_1_unless_accepted(
        good: M3GDConfig, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """`m3gd run --only geometry`: the verdict lines after the summary; exit 1 with the
    failed camera named in one line; `--accept-geometry front` exits 0 saying it accepted."""
    import yaml
    from typer.testing import CliRunner

    from cli.app import app
    from schemas.config import config_to_dict

    real = gv.body_track
    monkeypatch.setattr(gc, "body_track", lambda idx: _turned(
        gv.Poses.of(real(idx)), "front", "y", 5.0).body)
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(config_to_dict(good)))
    args = ["-c", str(path), "run", "--local", "--only", "geometry", "--force", "geometry"]
    failed = CliRunner().invoke(app, args)
    assert failed.exit_code == 1, failed.output
    out = " ".join(failed.output.split())  # the console wraps long lines
    assert f"geometry {REC}/front: failed:" in out and f"geometry {REC}/left: ok:" in out
    assert f"failed geometry {REC}: GeometryFailed: geometry failed in recording {REC}" in out
    accepted = CliRunner().invoke(app, [*args, "--accept-geometry", "front"])
    assert accepted.exit_code == 0, accepted.output
    assert "(accepted)" in " ".join(accepted.output.split())
