"""Storage benchmark on a small cache: figures present and consistent (no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.app import app
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
