"""Storage benchmark on a small cache: figures present and consistent (no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
from schemas.config import M3GDConfig
from tests.model.cache_fixture import build_cache


@pytest.fixture(scope="module")
def out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("moto.server")
    path = tmp_path_factory.mktemp("storage")
    build_cache(path)
    mission = path / "recordings" / "m0"  # a stand-in mission for the staging figures
    mission.mkdir(parents=True)
    for name in ("a.bag", "b.bag"):
        (mission / name).write_bytes(bytes(range(256)) * 64)
    return path


def test_bench_storage_json(out: Path) -> None:
    result = CliRunner().invoke(app, ["bench", "storage", "--json", "--output", str(out),
                                      "--rounds", "1"])
    assert result.exit_code == 0, result.output
    fig = json.loads(result.output)
    assert fig["clips"] == 22  # 2 cameras x 11 clips of recording r0 (the train split)
    # whole-shard reads: a few requests per clip; ranged reads: several per array and view
    assert 0 < fig["requests_per_clip_read"] < fig["requests_per_clip_read_range"]
    assert fig["requests_per_clip_read_warm"] == 0 and fig["cache_hit_rate_epoch2"] == 1.0
    assert 0 < fig["cache_hit_rate_epoch1"] < 1
    assert fig["s3_clip_read_over_local"] > 0 and fig["s3_range_clip_read_over_local"] > 0
    assert 0 < fig["bytes_fetched_epoch1"] < fig["output_bytes"]  # r0's shards only
    assert fig["mission_files"] == 2 and fig["mission_bytes"] == 2 * 256 * 64
    assert fig["stage_requests_per_file"] >= 1 and fig["s3_stage_over_local_copy"] > 0


def test_write_bench_runs_the_same_run_on_both(tmp_path: Path) -> None:
    """The write figures: the same (very small) run on local disk and on the S3 server; the
    store ends up with the local run's files as objects (the manifest's bytes may differ)."""
    from bench.loader_bench import tiny_config
    from bench.storage_write import run_write_bench
    from bench.support.local_s3 import environment, local_s3
    from dags.graph import STAGES, stage_names

    def config(out: Path) -> M3GDConfig:
        cfg = tiny_config(out)
        return cfg.model_copy(update={"synth": cfg.synth.model_copy(
            update={"scenes": ["corridor"], "seconds": 1.0})})

    with local_s3(tmp_path / "moto.log") as server, environment(server.env):
        server.create_bucket("m3gd-write")
        fig = run_write_bench(config, STAGES, tmp_path, server, "m3gd-write", rounds=1)
    assert fig["s3_write_over_local"] > 0 and set(fig["s3_write_over_local_by_stage"]) == set(
        stage_names())
    assert fig["write_s3_objects"] == fig["write_local_files"] > 0
    assert abs(fig["write_s3_bytes"] - fig["write_local_bytes"]) < 100
    assert fig["write_requests"]["PUT"] >= fig["write_s3_objects"]
    assert "POST" not in fig["write_requests"]  # small objects: one PUT, no multipart upload
