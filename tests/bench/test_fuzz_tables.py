"""The table repair loop of `m3gd bench fuzz`: every kind of table and metadata file,
damaged, is named by verify or run and rewritten byte-identical to a clean run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.fuzz_tables import damage_file, file_kind, run_table_repair, summarize_tables

NO_GEOMETRY = {"geometry": {"enabled": False}}
"""The geometry stage's table records its wall time (`seconds`), which no rerun reproduces:
left out here so that every other file is compared byte for byte."""


def test_file_kinds_name_the_table() -> None:
    assert file_kind(Path("index/rec/selection.parquet")) == "index/selection"
    assert file_kind(Path("stats/view_stats/rec.parquet")) == "stats/view_stats"
    assert file_kind(Path("cache.zarr/rec/front/zarr.json")) == "cache group zarr.json"
    assert file_kind(Path("cache.zarr/zarr.json")) == "cache root zarr.json"
    assert file_kind(Path("cache.zarr/rec/zarr.json")) == "cache recording zarr.json"
    assert file_kind(Path("cache.zarr/rec/front/g/zarr.json")) == "cache array zarr.json"
    assert file_kind(Path("clips.parquet")) == "clips.parquet"


@pytest.mark.parametrize("how", ["flip", "cut", "delete"])
def test_each_damage_changes_the_file(tmp_path: Path, how: str) -> None:
    path = tmp_path / "t.parquet"
    path.write_bytes(bytes(range(200)))
    damage_file(path, how, np.random.default_rng(3))
    assert not path.exists() if how == "delete" else path.read_bytes() != bytes(range(200))


def test_the_summary_counts_silent_and_unequal_rounds() -> None:
    from bench.fuzz_tables import TableRound

    ok = TableRound("index/images", "f", "flip", True, True, True, False, [], [])
    silent = TableRound("index/images", "f", "flip", False, False, True, False, ["x"], [])
    figures = summarize_tables([ok, silent])
    assert figures["tables_damaged_silently"] == 1
    assert figures["tables_repaired_not_identical"] == 1
    assert figures["flips_detected"] == {"index/images": "1/2"}
    assert figures["readable_after_flip"] == {"index/images": "2/2"}


@pytest.mark.slow
def test_every_table_kind_flipped_and_cut_is_named_and_repaired(tmp_path: Path) -> None:
    """Was: a flipped bit in selection.parquet, sweeps.parquet, a statistics table or
    clips.parquet left a readable table with a changed row (verify exit 0, run up to date);
    a cut images.parquet or clips.parquet was not redone; a damaged group zarr.json ended
    run in a JSONDecodeError; a garbled array, recording-group or root zarr.json ended verify
    in a traceback (or passed). Two rounds per kind: a flip (verify, then run) and a cut (run
    alone)."""
    figures = run_table_repair(tmp_path, None, 0, NO_GEOMETRY)
    assert figures["tables_rounds"] >= 26, figures
    for key in ("tables_damaged_silently", "tables_repaired_not_identical",
                "tables_still_damaged", "tables_failed_items"):
        assert figures[key] == 0, (key, figures["tables_failures"])
    assert all(a == b for a, b in (v.split("/") for v in figures["flips_detected"].values()))
    assert {"index/selection", "index/sweeps", "index/images", "stats/view_stats",
            "clips.parquet", "cache group zarr.json", "cache root zarr.json",
            "cache recording zarr.json", "cache array zarr.json"} \
        <= set(figures["flips_detected"])


def test_every_single_bit_flip_of_a_guarded_table_is_detected(tmp_path: Path) -> None:
    """A flip that still parses (a changed row) is named by its checksum all the same."""
    import pyarrow as pa

    from bench.fuzz_tables import flip_detection
    from schemas.tables import write_table

    schema = pa.schema([("frame", pa.int64()), ("dtau_s", pa.float64())])
    table = pa.table({"frame": list(range(40)), "dtau_s": [0.01 * k for k in range(40)]})
    write_table(table, schema, tmp_path / "out" / "index" / "rec" / "selection.parquet")
    found = flip_detection(tmp_path / "out", tmp_path / "flips", 40, np.random.default_rng(1))
    counts = found["index/selection"]
    assert counts["flips"] == counts["detected"] == 40 and counts["parses"] > 0, counts
