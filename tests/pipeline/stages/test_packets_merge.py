"""Several LiDARs merged into one packet (`select.lidar: [hesai, livox]`) on a synthetic rig
whose second LiDAR (`synth.second_lidar`) is mounted elsewhere, tilted down and sweeps half a
period after the first: it sees other points at other times."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zarr

from schemas.channels import DELTA_TAU, LOG1P_MEAN_DEPTH, VALIDITY, channel_index
from schemas.config import M3GDConfig, SynthConfig, parse_config
from schemas.recording_index import (
    SELECTION,
    SELECTION_LIDARS,
    SWEEPS,
    read_index_table,
    table_path,
)

LIDARS = {"hesai": {"topic": "/boxi/hesai/points_undistorted", "frame": "hesai_lidar"},
          "livox": {"topic": "/livox/lidar", "frame": "livox_frame"}}
RUNS: dict[str, Any] = {"both": ["hesai", "livox"], "hesai": "hesai", "livox": "livox"}


def _config(out: Path, mission: Path, lidar: Any) -> M3GDConfig:
    from tests.dags.conftest import tiny_raw

    raw = tiny_raw(out, [mission])
    raw["ingest"]["cameras"] = ["front"]
    raw["ingest"]["topics"] = {"lidars": LIDARS}
    raw["select"] = {"lidar": lidar}
    raw["packets"] = {"mode": "geom_only"}
    return parse_config(raw)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, M3GDConfig]:
    """One mission with two LiDARs, run through ingest, select and packets three times: both
    LiDARs merged, and each alone."""
    from dags.graph import STAGES
    from pipeline.run.service import run_stages
    from pipeline.synth.api import synthesize

    base = tmp_path_factory.mktemp("merge")
    synthesize(base / "rec", SynthConfig(seconds=1.2, image_width=192, image_height=128,
                                         points_per_sweep=4096, cameras=["front"],
                                         second_lidar=True, speed_mps=2.0,
                                         yaw_rate_max_rps=1.5, yaw_period_s=2.0),
               "corridor", mission="m")
    stages = [s for s in STAGES if s.name in ("synth", "ingest", "select", "packets")]
    out = {}
    for name, lidar in RUNS.items():
        cfg = _config(base / name, base / "rec" / "m", lidar)
        assert not any(s.failed for s in run_stages(cfg, stages).summaries)
        out[name] = cfg
    return out


def _g(cfg: M3GDConfig) -> tuple[np.ndarray, np.ndarray]:
    """(g (V, n_g, H, W), valid (V,)) of the front camera."""
    group = zarr.open_group(str(cfg.layout.cache / "m" / "front"), mode="r")
    return np.asarray(group["g"][:]), np.asarray(group["valid"][:])


def test_selection_has_a_row_per_view_and_lidar_with_its_own_sweep(
        runs: dict[str, M3GDConfig]) -> None:  # fmt: skip
    idx = runs["both"].layout.index_of("m")
    views = read_index_table(table_path(idx, "selection"), SELECTION).to_pylist()
    rows = read_index_table(table_path(idx, "selection_lidars"), SELECTION_LIDARS).to_pylist()
    lidar_of = {r["sweep"]: r["lidar"] for r in
                read_index_table(table_path(idx, "sweeps"), SWEEPS).to_pylist()}
    assert len(rows) == 2 * len(views)
    by = {(r["frame"], r["lidar"]): r for r in rows}
    for v in views:  # the reference's rows are the views' own
        ref = by[(v["frame"], "hesai")]
        assert (ref["sweep"], ref["dtau_s"], ref["status"]) == (v["sweep"], v["dtau_s"],
                                                                v["status"])
    ok = [r for r in rows if r["status"] == "ok"]
    assert {r["lidar"] for r in ok} == {"hesai", "livox"}
    assert all(lidar_of[r["sweep"]] == r["lidar"] for r in ok)
    gaps = [abs(by[(f, "livox")]["sweep_stamp_ns"] - by[(f, "hesai")]["sweep_stamp_ns"])
            for f, name in by if name == "hesai" and by[(f, "livox")]["status"] == "ok"
            and by[(f, "hesai")]["status"] == "ok"]
    assert gaps and min(gaps) > 20_000_000  # the second LiDAR sweeps at other times
    single = runs["hesai"].layout.index_of("m")
    assert not table_path(single, "selection_lidars").exists()


def test_merged_packets_see_both_lidars_points(runs: dict[str, M3GDConfig]) -> None:
    v = channel_index(VALIDITY)
    (gb, ok), (gh, _), (gl, _) = (_g(runs[k]) for k in ("both", "hesai", "livox"))
    occ = {k: g[ok, v] > 0 for k, g in (("both", gb), ("hesai", gh), ("livox", gl))}
    assert np.all(occ["both"] >= occ["hesai"]) and np.all(occ["both"] >= occ["livox"])
    assert np.array_equal(occ["both"], occ["hesai"] | occ["livox"])
    only_livox = occ["livox"] & ~occ["hesai"]
    assert only_livox.sum() > 0.05 * occ["hesai"].sum()  # other points, not a copy


def test_a_cell_carries_the_delta_tau_and_depth_of_the_lidar_that_sees_it(
        runs: dict[str, M3GDConfig]) -> None:  # fmt: skip
    v, dt, d = channel_index(VALIDITY), channel_index(DELTA_TAU), channel_index(LOG1P_MEAN_DEPTH)
    (gb, ok), (gh, _), (gl, _) = (_g(runs[k]) for k in ("both", "hesai", "livox"))
    gb, gh, gl = gb[ok], gh[ok], gl[ok]
    oh, ol = gh[:, v] > 0, gl[:, v] > 0
    for only, single in ((oh & ~ol, gh), (ol & ~oh, gl)):
        assert only.any()
        np.testing.assert_array_equal(gb[:, dt][only], single[:, dt][only])
        np.testing.assert_allclose(gb[:, d][only], single[:, d][only], rtol=1e-5)
    both = oh & ol
    lo = np.minimum(gh[:, dt], gl[:, dt])[both]
    hi = np.maximum(gh[:, dt], gl[:, dt])[both]
    mixed = gb[:, dt][both]
    assert np.all((mixed >= lo - 1e-7) & (mixed <= hi + 1e-7))
    per_view = [np.unique(gb[i, dt][gb[i, v] > 0]).size for i in range(len(gb))]
    assert max(per_view) > 2  # the channel varies within a view: two sweeps and their means


def _livox_depth_error(cfg: M3GDConfig, through_reference: bool) -> float:
    """Median abs-rel against the true depth of the second LiDAR's cells, its points carried
    by its own sweep's pose (as merged) or, wrongly, by the reference sweep's pose."""
    from packets.accuracy import abs_rel, packet_depth
    from packets.assemble import build_packet
    from pipeline.analysis.accuracy import view_truths
    from pipeline.ingest.sources.sweep_reader import load_sweep
    from schemas.recording_index import CALIBRATION

    idx = cfg.layout.index_of("m")
    rows = {(r["frame"], r["lidar"]): r for r in read_index_table(
        table_path(idx, "selection_lidars"), SELECTION_LIDARS).to_pylist()}
    sweeps = {r["sweep"]: r for r in read_index_table(table_path(idx, "sweeps"),
                                                      SWEEPS).to_pylist()}
    calib = {r["sensor"]: np.reshape(r["T_base_sensor"], (4, 4)) for r in read_index_table(
        table_path(idx, "calibration"), CALIBRATION).to_pylist()}
    T_hesai_livox = np.linalg.inv(calib["hesai"]) @ calib["livox"]
    errors = []
    for view in view_truths(cfg, "m"):
        row = rows[(view.frame, "livox")]
        if row["status"] != "ok":
            continue
        T = np.reshape(row["T_cam_lidar"], (4, 4))
        if through_reference:
            T = np.reshape(rows[(view.frame, "hesai")]["T_cam_lidar"], (4, 4)) @ T_hesai_livox
        xyz = load_sweep(Path(cfg.ingest.recordings[0]), sweeps[row["sweep"]]).xyz
        pkt = build_packet(xyz, view.K_out, T, (cfg.ingest.out_height, cfg.ingest.out_width),
                           row["dtau_s"], None, mode="geom_only")
        depth = packet_depth(pkt.g)
        ok = np.isfinite(depth) & np.isfinite(view.ref.median) & ~view.ref.border
        errors.append(abs_rel(depth[ok], view.ref.median[ok]))
    return float(np.median(np.concatenate(errors)))


def test_each_lidar_is_carried_by_its_own_sweeps_pose(runs: dict[str, M3GDConfig]) -> None:
    """Against the true depth maps: the merged packets are as accurate as either LiDAR alone,
    and carrying the second LiDAR by the reference sweep's pose (half a period away, the body
    turning) is measurably worse than by its own."""
    from pipeline.analysis.accuracy import recording_accuracy

    med = {}
    for name, cfg in runs.items():
        t = recording_accuracy(cfg, "m")
        keep = ~np.asarray(t["border"].to_numpy(zero_copy_only=False), bool)
        med[name] = float(np.nanmedian(np.asarray(t["abs_rel"].to_numpy(zero_copy_only=False),
                                                  np.float64)[keep]))
    assert med["both"] <= 1.2 * max(med["hesai"], med["livox"]), med
    own, ref = (_livox_depth_error(runs["both"], r) for r in (False, True))
    assert own < 0.7 * ref, (own, ref, med)


def test_a_lost_merge_table_is_redone_and_a_stale_one_removed(
        runs: dict[str, M3GDConfig], tmp_path: Path) -> None:  # fmt: skip
    """The merge table is a select output: deleted, the next run writes it again, the same;
    a run that stops merging removes it (packets never read a stale one)."""
    from dags.graph import STAGES
    from pipeline.run.service import run_stages

    stages = [s for s in STAGES if s.name in ("synth", "ingest", "select")]
    mission = Path(runs["both"].ingest.recordings[0])
    cfg = _config(tmp_path / "out", mission, ["hesai", "livox"])
    assert not any(s.failed for s in run_stages(cfg, stages).summaries)
    path = table_path(cfg.layout.index_of("m"), "selection_lidars")
    first = path.read_bytes()
    path.unlink()
    assert not any(s.failed for s in run_stages(cfg, stages).summaries)
    assert path.read_bytes() == first
    single = _config(tmp_path / "out", mission, "hesai")
    assert not any(s.failed for s in run_stages(single, stages).summaries)
    assert not path.exists()


def test_the_plan_costs_every_merged_lidars_sweeps(runs: dict[str, M3GDConfig]) -> None:
    from pipeline.stages.packets_plan import recording_costs
    from schemas.cache_layout import GroupAttrs

    cfg = runs["both"]
    group = zarr.open_group(str(cfg.layout.cache / "m" / "front"), mode="r")
    attrs = [GroupAttrs.from_attrs(dict(group.attrs), "m/front")]
    idx = cfg.layout.index_of("m")
    one, merged = recording_costs(idx, attrs), recording_costs(idx, attrs, merges=True)
    assert 1.5 * one[0] < merged[0] < 2.5 * one[0]  # two LiDARs of equal sweeps
    assert len(one[1]) == len(merged[1])
