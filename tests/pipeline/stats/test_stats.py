"""Statistics: shard rows, exact merge per recording, DuckDB queries and summaries."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from packets.running_stats import ChannelStats
from packets.support import SupportSets
from pipeline.analysis.query import query, summary
from pipeline.stats.merge import (
    LatentPart,
    latent_part_path,
    merge_latent_parts,
    merge_recording,
    write_latent_part,
)
from pipeline.stats.rows import ShardStats
from schemas.errors import DataError


def _support(cells: list[int], depths: list[float]) -> SupportSets:
    return SupportSets(np.arange(len(cells), dtype=np.int64), np.asarray(cells, np.int64),
                       np.asarray(depths, np.float64), (2, 3), n_points=len(cells) + 2,
                       n_too_near=1)


def _write_shards(out: Path) -> None:
    for shard, frames in enumerate([(0, 1), (2,)]):
        part = ShardStats("rec", "front")
        for f in frames:
            if f == 1:
                part.add_view(f, 100 + f, None, 0.3, None, "dtau_exceeded")
            else:
                part.add_view(f, 100 + f, 90 + f, -0.01, _support([0, 0, 5], [2.0, 4.0, 10.0]),
                              None)
        part.write(out, shard)


def test_merge_and_query(tmp_path: Path) -> None:
    _write_shards(tmp_path)
    rows = merge_recording(tmp_path, "rec")
    assert rows == {"view_stats": 3, "cell_stats": 4}
    views = query(tmp_path, "SELECT * FROM view_stats ORDER BY frame").to_pylist()
    assert [v["frame"] for v in views] == [0, 1, 2]
    assert views[0]["supported_cells"] == 2 and views[0]["depth_mean_m"] == pytest.approx(16 / 3)
    assert views[1]["reject_reason"] == "dtau_exceeded"
    cells = query(tmp_path, "SELECT n, depth_mean_m, depth_var_m2 FROM cell_stats "
                            "WHERE frame = 0 ORDER BY row, col").to_pylist()
    assert cells == [{"n": 2, "depth_mean_m": 3.0, "depth_var_m2": 1.0},
                     {"n": 1, "depth_mean_m": 10.0, "depth_var_m2": 0.0}]
    assert cells[1] == query(tmp_path, "SELECT n, depth_mean_m, depth_var_m2 FROM cell_stats "
                                       "WHERE row = 1 AND col = 2 AND frame = 2").to_pylist()[0]
    path = tmp_path / "stats" / "view_stats" / "rec.parquet"
    assert pq.read_table(path).num_rows == 3  # any Parquet reader


def test_summaries(tmp_path: Path) -> None:
    _write_shards(tmp_path)
    merge_recording(tmp_path, "rec")
    dtau = summary(tmp_path, "dtau").to_pylist()[0]
    assert dtau["views"] == 3 and dtau["rejected"] == 1
    # the rejected view's 0.3 s stays out of the accepted figures and is reported apart
    assert dtau["max_abs_dtau_ms"] == 10.0 and dtau["p95_abs_dtau_ms"] == 10.0
    assert dtau["mean_dtau_ms"] == -10.0 and dtau["max_abs_dtau_rejected_ms"] == 300.0
    sparse = summary(tmp_path, "sparse_views").to_pylist()
    assert [r["frame"] for r in sparse] == [0, 2]
    occ = {(r["row"], r["col"]): r["views_supported"] for r in summary(tmp_path, "occupancy")
           .to_pylist()}
    assert occ == {(0, 0): 2, (1, 2): 2}
    with pytest.raises(ValueError, match="unknown summary"):
        summary(tmp_path, "nope")


def test_bad_sql_names_the_output(tmp_path: Path) -> None:
    _write_shards(tmp_path)
    merge_recording(tmp_path, "rec")
    with pytest.raises(ValueError, match="query failed"):
        query(tmp_path, "SELECT nope FROM view_stats")


def _parts(out: Path, x: np.ndarray, bounds: list[tuple[int, int]]) -> list[LatentPart]:
    """Write one latent part per view range of `x` (one row per view); their identities."""
    parts = []
    for i, (a, b) in enumerate(bounds):
        part = LatentPart("rec/front", i, (a, b), b - a, f"key{i}")
        write_latent_part(latent_part_path(out, "rec", "front", i), ChannelStats.of(x[a:b]),
                          part)
        parts.append(part)
    return parts


def test_latent_stats_merge_exactly(tmp_path: Path) -> None:
    x = np.random.default_rng(0).normal(5.0, 2.0, size=(100, 4))
    parts = _parts(tmp_path, x, [(0, 30), (30, 31), (31, 100)])
    merged, groups, removed = merge_latent_parts(tmp_path, parts)
    np.testing.assert_allclose(merged.mean, x.mean(0), rtol=1e-12)
    np.testing.assert_allclose(merged.variance, x.var(0), rtol=1e-10)
    assert groups == {"rec/front": 100} and removed == []


def test_latent_parts_of_another_layout_are_removed_or_refused(tmp_path: Path) -> None:
    """Was: after `cache.shard_views` 4 -> 8, the parts of shards 2..4 of the old layout were
    merged too (latent_norm over 1200 views instead of 720; with other channels, a broadcast
    error on every rerun)."""
    x = np.random.default_rng(1).normal(size=(40, 3))
    parts = _parts(tmp_path, x, [(0, 8), (8, 16), (16, 24), (24, 32), (32, 40)])
    now = [LatentPart("rec/front", 0, (0, 16), 16, "key0"),
           LatentPart("rec/front", 1, (16, 32), 16, "key1")]
    with pytest.raises(DataError, match=r"front-000000.json: latent statistics of another "
                                        r"cache layout \(views \[0, 8\], the cache has "
                                        r"\[0, 16\]\); m3gd run --force encode"):
        merge_latent_parts(tmp_path, now)
    assert not latent_part_path(tmp_path, "rec", "front", 4).exists()  # past the last: removed
    with pytest.raises(DataError, match="cache_key 'key1', the cache has 'other'"):
        merge_latent_parts(tmp_path, [parts[0], LatentPart("rec/front", 1, (8, 16), 8, "other")])
    old = latent_part_path(tmp_path, "rec", "front", 0)
    old.write_text(json.dumps(ChannelStats.of(x).to_dict()))  # the first format: no identity
    with pytest.raises(DataError, match=r"front-000000.json: .* \(an earlier format\)"):
        merge_latent_parts(tmp_path, parts[:2])


def test_merge_recording_takes_exactly_the_cache_shards(tmp_path: Path) -> None:
    _write_shards(tmp_path)
    extra = tmp_path / "stats" / "parts" / "rec" / "view_stats-front-000007.parquet"
    extra.write_bytes((tmp_path / "stats" / "parts" / "rec" /
                       "view_stats-front-000000.parquet").read_bytes())
    assert merge_recording(tmp_path, "rec", {"front": 2}) == {"view_stats": 3, "cell_stats": 4}
    assert not extra.exists()
    with pytest.raises(DataError, match=r"cell_stats-front-000002\.parquet: statistics part "
                                        r"missing \(2 in all\)"):
        merge_recording(tmp_path, "rec", {"front": 3})


def test_query_over_s3_equals_local(tmp_path: Path, s3: str) -> None:
    from tests.s3_fixture import upload

    _write_shards(tmp_path)
    merge_recording(tmp_path, "rec")
    upload(tmp_path, s3)
    for sql in ("SELECT * FROM view_stats ORDER BY frame",
                "SELECT * FROM cell_stats ORDER BY frame, row, col",
                "SELECT recording, count(*) AS n FROM view_stats GROUP BY recording"):
        assert query(s3, sql).equals(query(tmp_path, sql)), sql
    for name in ("dtau", "occupancy", "sparse_views", "rejects"):
        assert summary(s3, name).equals(summary(tmp_path, name)), name
    with pytest.raises(ValueError, match=r"query failed over s3://m3gd-test-\d+/out/stats"):
        query(s3, "SELECT nope FROM view_stats")
