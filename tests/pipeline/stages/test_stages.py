"""Stage glue end to end on tiny bags: run once, resumable after a crash, modes, faults."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import zarr

import pipeline.stages.packets as packets_stage
from dags.graph import STAGES
from pipeline.run.service import run_stages
from pipeline.stages.common import image_encoder, point_encoder
from schemas.config import M3GDConfig, parse_config
from tests.dags.outputs import assert_same_outputs
from tests.pipeline.ingest.bagkit import Mission, write_mission

CAMS = ("front",)  # the tiny bag kit calibrates one camera; synth tests cover three


@pytest.fixture(scope="module")
def missions(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    base = tmp_path_factory.mktemp("missions")
    return [write_mission(base, Mission(seconds=2.0, cameras=CAMS), name=f"m{i}")
            for i in range(2)]


def _cfg(out: Path, missions: list[Path], **extra: Any) -> M3GDConfig:
    raw: dict[str, Any] = {
        "output_dir": str(out),
        "ingest": {"recordings": [str(m) for m in missions], "out_height": 112,
                   "out_width": 168, "cameras": list(CAMS)},
        "encoders": {"image_channels": 588, "point_channels": 16},
        "cache": {"shard_views": 8}, "dag": {"retries": 0},
        "clips": {"eval_clips_per_recording": 6},
    }
    for key, value in extra.items():
        raw.setdefault(key, {}).update(value)
    return parse_config(raw)


def _run(cfg: M3GDConfig) -> dict[str, Any]:
    summaries = run_stages(cfg, STAGES).summaries
    return {s.name: s for s in summaries}


def _selected_sweeps(out: Path) -> int:
    total = 0
    for sel in sorted(out.glob("index/*/selection.parquet")):
        rows = pq.read_table(sel).to_pylist()
        total += len({r["sweep"] for r in rows if r["status"] == "ok"})
    return total


def test_encoders_run_once_across_reruns(missions: list[Path], tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, missions)
    image_encoder.cache_clear()
    point_encoder.cache_clear()
    first = _run(cfg)
    assert not any(s.failed for s in first.values())
    img, pts = image_encoder(cfg.encoders), point_encoder(cfg.encoders)
    valid = sum(int(zarr.open_array(str(p), mode="r")[:].sum())
                for p in tmp_path.glob("cache.zarr/*/*/valid"))
    assert valid == first["encode"].done > 0
    assert img.n_encoded == valid  # every valid view encoded exactly once
    sweeps = _selected_sweeps(tmp_path)
    assert sweeps > 0
    assert pts.n_encoded == sweeps  # every selected sweep encoded exactly once
    again = _run(cfg)
    assert all(s.done == 0 for s in again.values())
    assert img.n_encoded == valid and pts.n_encoded == sweeps


def test_crash_mid_packets_resumes_to_same_outputs(missions: list[Path], tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    ref = tmp_path / "ref"
    _run(_cfg(ref, missions))
    out = tmp_path / "out"
    real = packets_stage.mark_shard_done
    calls = {"n": 0}

    def crash_after_first(*args: Any) -> None:
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt("simulated kill while writing a shard")
        real(*args)

    monkeypatch.setattr(packets_stage, "mark_shard_done", crash_after_first)
    with pytest.raises(KeyboardInterrupt):
        _run(_cfg(out, missions))
    marks = list(out.glob("cache_done/*/*/packets.*.json"))
    assert len(marks) == 1  # the shard being written when killed is not marked complete
    monkeypatch.setattr(packets_stage, "mark_shard_done", real)
    resumed = _run(_cfg(out, missions))
    assert not any(s.failed for s in resumed.values())
    assert_same_outputs(ref, out)


def test_recording_whose_packets_failed_is_left_out_of_the_clips(
        missions: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    real = packets_stage.mark_shard_done

    def fail_m1(group: Any, *args: Any) -> None:
        if group.path.startswith("m1/"):
            raise ValueError("m1: injected packets failure")
        real(group, *args)

    monkeypatch.setattr(packets_stage, "mark_shard_done", fail_m1)
    first = _run(_cfg(tmp_path, missions))
    assert "m1" in first["packets"].failed and first["clips"].done > 0
    clips = pq.read_table(tmp_path / "clips.parquet").to_pylist()
    assert {c["recording"] for c in clips} == {"m0"}
    told = [m for m in (r.getMessage() for r in caplog.records)
            if "left out of the clip index" in m]
    assert len(told) == len(CAMS) and all("m1/" in t for t in told)
    monkeypatch.setattr(packets_stage, "mark_shard_done", real)
    second = _run(_cfg(tmp_path, missions))  # the rerun completes m1 and the clips
    assert not any(s.failed for s in second.values())
    clips = pq.read_table(tmp_path / "clips.parquet").to_pylist()
    assert {c["recording"] for c in clips} == {"m0", "m1"}


def test_packets_per_shard_row_equal_per_recording(missions: list[Path], tmp_path: Path) -> None:
    ref, rows, auto = tmp_path / "ref", tmp_path / "rows", tmp_path / "auto"
    _run(_cfg(ref, missions, packets={"items": "recording"}))
    # auto on 3 workers: splitting one of the two recordings shortens the schedule
    mixed = _run(_cfg(auto, missions, dag={"workers": 3}))
    keys = [k for k in (auto / "manifest.json").read_text().split('"') if k.startswith("m")]
    assert len(missions) < mixed["packets"].items, keys
    assert_same_outputs(ref, auto)
    point_encoder.cache_clear()
    point_encoder.cache_clear()
    out = _run(_cfg(rows, missions, packets={"items": "shard_row"}))
    n_items = out["packets"].items
    assert n_items > len(missions)  # several shard rows per recording: more parallel tasks
    assert_same_outputs(ref, rows)
    encoded, selected = point_encoder.cache_info(), _selected_sweeps(rows)
    assert encoded.currsize == 1
    pts = point_encoder(_cfg(rows, missions).encoders).n_encoded
    # a sweep is encoded once per shard row that uses it: at most once more per extra row
    assert selected <= pts <= selected + len(CAMS) * (n_items - len(missions))


def test_geom_only_never_encodes_points(missions: list[Path], tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, missions, packets={"mode": "geom_only"})
    point_encoder.cache_clear()
    _run(cfg)
    group = zarr.open_group(str(tmp_path / "cache.zarr"), mode="r")["m0/front"]
    assert "g" in group and "h_cells" not in group
    assert group.attrs["packet_mode"] == "geom_only"
    assert point_encoder.cache_info().currsize == 0


def test_packets_match_cache_metadata(missions: list[Path], tmp_path: Path) -> None:
    _run(_cfg(tmp_path, missions))
    group = zarr.open_group(str(tmp_path / "cache.zarr"), mode="r")["m1/front"]
    g, valid = group["g"][:], group["valid"][:]
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(group["h_cells"][:].astype(np.float32)))
    assert np.all(g[~valid] == 0)
    dtau = group["dtau_s"][:]
    occupied = g[:, 0] == 1
    np.testing.assert_allclose(g[:, 5][occupied], np.broadcast_to(dtau[:, None, None],
                                                                   g[:, 5].shape)[occupied])
    assert group.attrs["point_encoder"]["name"] == "fpfh"
    packed = group["h_cells"][:]  # (N, H*W, C_u): one row per occupied cell, then zeros
    assert occupied.any() and np.abs(packed).max() > 0
    for n, count in enumerate(occupied.reshape(len(g), -1).sum(axis=1)):
        assert not packed[n, count:].any()


def test_cached_packet_equals_one_computed_from_the_raw_sweep(missions: list[Path],
                                                               tmp_path: Path) -> None:
    from packets.assemble import SweepFeatures, packet_from_support, view_support
    from pipeline.ingest.sources.sweep_reader import load_sweep
    from pipeline.stages.common import index_path
    from schemas.missions import mission_of
    from schemas.recording_index import SELECTION, SWEEPS, read_index_table
    from store.cache_io import read_clip

    cfg = _cfg(tmp_path, missions)
    _run(cfg)
    index = index_path(cfg, "m1")
    sel = [r for r in read_index_table(index / "selection.parquet", SELECTION).to_pylist()
           if r["camera"] == "front" and r["status"] == "ok"]
    row = sel[len(sel) // 2]
    sweeps = {r["sweep"]: r for r in read_index_table(index / "sweeps.parquet", SWEEPS).to_pylist()}
    sweep = load_sweep(mission_of(cfg, "m1"), sweeps[row["sweep"]])
    feat = point_encoder(cfg.encoders).encode(sweep.xyz, sweep.intensity)
    sup = view_support(sweep.xyz, np.reshape(row["K_out"], (3, 3)),
                       np.reshape(row["T_cam_lidar"], (4, 4)),
                       (cfg.ingest.out_height, cfg.ingest.out_width),
                       min_depth_m=cfg.packets.min_depth_m)
    pkt = packet_from_support(sup, row["dtau_s"], SweepFeatures.from_array(feat), mode="full")
    group = zarr.open_group(str(tmp_path / "cache.zarr"), mode="r")["m1/front"]
    assert (pkt.g[0] == 1).sum() >= 3  # a view with real LiDAR support
    np.testing.assert_allclose(group["g"][row["frame"]], pkt.g, rtol=1e-6, atol=1e-6)
    h = read_clip(tmp_path / "cache.zarr" / "m1" / "front", ["h"], [row["frame"]])["h"][0]
    np.testing.assert_allclose(np.moveaxis(h, -1, 0).astype(np.float32),
                               pkt.h.astype(np.float16).astype(np.float32), rtol=1e-3, atol=1e-3)


def test_latent_norm_of_a_cache_where_nothing_was_encoded_is_a_warning(tmp_path: Path) -> None:
    from pipeline.run.stage import Item
    from pipeline.stages.stats import NORM_ITEM, run_stats
    from schemas.config import M3GDConfig

    result = run_stats(M3GDConfig(output_dir=tmp_path), Item(NORM_ITEM, "key"))
    assert result.done == 0
    assert result.warnings == ["no view was encoded, so the cache has no latent normalization yet"]
    assert not (tmp_path / "cache.zarr").exists()
