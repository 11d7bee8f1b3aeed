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
from pipeline.run.executors import LocalExecutor
from pipeline.run.runner import Runner
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
    summaries = Runner(cfg, STAGES, progress=False).run(LocalExecutor())
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


def test_geom_only_never_encodes_points(missions: list[Path], tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, missions, packets={"mode": "geom_only"})
    point_encoder.cache_clear()
    _run(cfg)
    group = zarr.open_group(str(tmp_path / "cache.zarr"), mode="r")["m0/front"]
    assert "g" in group and "h" not in group
    assert group.attrs["packet_mode"] == "geom_only"
    assert point_encoder.cache_info().currsize == 0


def test_packets_match_cache_metadata(missions: list[Path], tmp_path: Path) -> None:
    _run(_cfg(tmp_path, missions))
    group = zarr.open_group(str(tmp_path / "cache.zarr"), mode="r")["m1/front"]
    g, valid = group["g"][:], group["valid"][:]
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(group["h"][:].astype(np.float32)))
    assert np.all(g[~valid] == 0)
    dtau = group["dtau_s"][:]
    occupied = g[:, 0] == 1
    np.testing.assert_allclose(g[:, 5][occupied], np.broadcast_to(dtau[:, None, None],
                                                                   g[:, 5].shape)[occupied])
    assert group.attrs["point_encoder"]["name"] == "fpfh"
