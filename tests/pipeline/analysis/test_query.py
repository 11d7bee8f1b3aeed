"""`stats query`'s DuckDB: every Parquet table by name (statistics, clips, index tables with
their recording), nothing else reachable unless files are allowed, one-line refusals."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.analysis.query import query, table_files
from schemas.errors import DataError


def _output(root: Path) -> Path:
    """An output folder with statistics, a clip index, two recordings' index tables, and
    files that are no tables (shard parts, a temp file, a hidden one)."""
    def put(rel: str, **cols: list[object]) -> None:
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table(cols), path)

    put("stats/view_stats/recording=r1/part-0.parquet", recording=["r1"] * 2, frame=[0, 1])
    put("stats/view_stats/recording=r2/part-0.parquet", recording=["r2"], frame=[5])
    put("stats/alignment.parquet", pair=["latents_l0:h"], value=[0.5])
    put("stats/parts/r1/view_stats-front-000000.parquet", recording=["r1"], frame=[99])
    put("clips.parquet", clip=[0, 1, 2])
    put("index/r1/rejects.parquet", topic=["/cam"], reason=["corrupt_jpeg"])
    put("index/r2/rejects.parquet", topic=["/lidar", "/cam"], reason=["empty_sweep", "x"])
    put("index/r1/selection.parquet", camera=["front"], frame=[0])
    put("index/r1/.images.parquet.tmp", camera=["front"])
    put("index/r1/.hidden.parquet", camera=["front"])
    return root


def test_every_table_by_name_with_index_tables_by_recording(tmp_path: Path) -> None:
    out = _output(tmp_path)
    rows = query(out, "SELECT recording, count(*) AS n FROM rejects GROUP BY ALL ORDER BY 1")
    assert rows.to_pylist() == [{"recording": "r1", "n": 1}, {"recording": "r2", "n": 2}]
    assert query(out, "SELECT recording, frame FROM selection").to_pylist() == [
        {"recording": "r1", "frame": 0}]
    assert query(out, "SELECT sum(frame) AS s FROM view_stats").to_pylist() == [{"s": 6}]
    assert query(out, "SELECT count(*) AS n FROM clips").to_pylist() == [{"n": 3}]
    assert query(out, "SELECT value FROM alignment").to_pylist() == [{"value": 0.5}]


def test_table_files_skips_parts_temp_and_hidden_files() -> None:
    keys = ["/o/stats/parts/r/view_stats-a-000000.parquet", "/o/index/r/.x.parquet",
            "/o/index/r/images.parquet.tmp", "/o/index/r/images.parquet",
            "/o/stats/cell_stats/recording=r/part-0.parquet", "/o/stats/a.parquet",
            "/o/clips.parquet", "/o/recordings/r/gt/poses.parquet", "/elsewhere/clips.parquet"]
    assert table_files(keys, "/o") == {
        "cell_stats": (["/o/stats/cell_stats/recording=r/part-0.parquet"], False),
        "a": (["/o/stats/a.parquet"], False), "clips": (["/o/clips.parquet"], False),
        "images": (["/o/index/r/images.parquet"], True)}


def test_a_missing_table_is_answered_with_the_tables_that_exist(tmp_path: Path) -> None:
    out = _output(tmp_path)
    with pytest.raises(DataError) as err:
        query(out, "SELECT * FROM nope")
    text = str(err.value)
    assert "\n" not in text
    assert "tables here: alignment, clips, rejects, selection, view_stats" in text
    with pytest.raises(DataError, match=r"table accuracy is written by `m3gd accuracy`: run "
                                        r"it first; tables here: alignment, clips"):
        query(out, "SELECT * FROM accuracy")


REFUSED = {
    "copy": "COPY (SELECT * FROM rejects) TO '{tmp}/x.csv'",
    "read_csv": "SELECT * FROM read_csv('/etc/passwd')",
    "read_parquet": "SELECT * FROM read_parquet('{tmp}/out/clips.parquet')",
    "attach": "ATTACH '{tmp}/db.duckdb' AS db",
    "install": "INSTALL httpfs",
    "load": "LOAD httpfs",
    "unlock": "SET enable_external_access = true",
    "unlock_config": "SET lock_configuration = false",
    "allow_dirs": "SET allowed_directories = ['/']",
    "export": "EXPORT DATABASE '{tmp}/exported'",
    "glob": "SELECT * FROM glob('/etc/*')",
}


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_sql_reaching_files_is_refused_in_one_line(tmp_path: Path, name: str) -> None:
    out = _output(tmp_path / "out")
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(DataError) as err:
        query(out, REFUSED[name].format(tmp=tmp_path))
    assert "\n" not in str(err.value)
    assert str(err.value).startswith("query refused: ") and "--allow-files" in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_allow_files_gives_sql_file_access(tmp_path: Path) -> None:
    out = _output(tmp_path / "out")
    target = tmp_path / "rejects.csv"
    query(out, f"COPY (SELECT topic FROM rejects ORDER BY topic) TO '{target}'", True)
    assert target.read_text().split() == ["topic", "/cam", "/cam", "/lidar"]
    again = query(out, f"SELECT count(*) AS n FROM read_csv('{target}')", allow_files=True)
    assert again.to_pylist() == [{"n": 3}]
