"""Every Parquet table a small run writes opens with pandas, pyarrow, polars and DuckDB, with no
option, and they agree on its rows and column types (`schemas.tables.STATS_LAYOUT_VERSION`)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import duckdb
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq
import pytest

from schemas.config import M3GDConfig
from schemas.tables import REPROJECTION_CONSISTENCY, write_table
from tests.pipeline.tiny_output import tiny_output

pl = pytest.importorskip("polars")

KINDS = {"string": {"string", "large_string", "str", "String", "VARCHAR"},
         "int": {"int16", "int32", "int64", "Int16", "Int32", "Int64", "SMALLINT", "INTEGER",
                 "BIGINT"},
         "float": {"double", "float64", "Float64", "DOUBLE"},
         "bool": {"bool", "boolean", "Boolean", "BOOLEAN"}}
PANDAS_ALSO = {"int": {"float"}, "list": {"object"}, "bool": {"object"}}
"""What pandas may show instead (a null in an int or bool column, a list as objects)."""


def _kind(type_name: str) -> str:
    """The family of a reader's type name: string, int, float, bool, list, or the name."""
    if type_name.startswith(("list<", "large_list<", "fixed_size_list<", "List(", "Array(")
                            ) or type_name.endswith("]"):
        return "list"
    return next((k for k, names in KINDS.items() if type_name in names), type_name)


@pytest.fixture(scope="module")
def cfg(tmp_path_factory: pytest.TempPathFactory) -> M3GDConfig:
    """The session's tiny output, with its accuracy table."""
    from pipeline.analysis.accuracy import run_accuracy

    cfg = tiny_output(tmp_path_factory)
    if not any((cfg.layout.stats / "accuracy").glob("*.parquet")):
        run_accuracy(cfg, plots=False)
    return cfg


def _eval_and_consistency(where: Path) -> list[Path]:
    """An `m3gd eval` per-target table (targets with and without reprojection and image
    baselines) and a consistency table, written by the product's writers."""
    from model.evaluate import TargetResult
    from model.scoring import target_rows
    from pipeline.analysis.model_eval import write_eval

    results = [TargetResult(0, 1, None, None, 12.5, 0.4, {"copy_source": (11.0, 0.3)}),
               TargetResult(1, 2, None, None, 13.0, 0.5,
                            {"copy_source": (11.5, 0.3), "reprojection": (14.0, 0.6)},
                            {"model": 0.1, "ground_truth": 0.05, "copy_source": 0.2,
                             "mean_latent": 0.3, "reprojection": 0.08}, 32)]
    stream = SimpleNamespace(clips=[{"clip_id": 0, "hard": False}, {"clip_id": 1, "hard": True}])
    summary = write_eval({"clips": 2}, target_rows(results, stream),  # type: ignore[arg-type]
                         where / "eval" / "eval.json")
    row = {f.name: (0 if pa.types.is_integer(f.type) else 0.5 if pa.types.is_floating(f.type)
                    else "x") for f in REPROJECTION_CONSISTENCY}
    consistency = where / "reprojection_consistency.parquet"
    write_table(pa.Table.from_pylist([row]), REPROJECTION_CONSISTENCY, consistency)
    return [summary.with_suffix(".parquet"), consistency]


def _tables(cfg: M3GDConfig, tmp: Path) -> list[Path]:
    """Each file table and each per-recording table folder of the output."""
    stats = cfg.layout.stats
    folders = [p for p in sorted(stats.iterdir()) if p.is_dir() and p.name != "parts"
               and any(p.glob("*.parquet"))]
    return [*sorted(cfg.layout.index.glob("*/*.parquet")), cfg.layout.clips, *folders,
            *_eval_and_consistency(tmp)]


def _read_all(path: Path, polars: bool = True) -> dict[str, tuple[int, dict[str, str]]]:
    """rows and column -> type name, as each reader opens `path` with no option (polars left
    out unless `polars`)."""
    s = str(path)
    df = pd.read_parquet(s)
    arrow = pq.read_table(s)
    data = pads.dataset(s).to_table()
    duck = duckdb.read_parquet(s)
    seen = {
        "pandas": (len(df), {c: str(t) for c, t in df.dtypes.items()}),
        "pyarrow.read_table": (arrow.num_rows, {f.name: str(f.type) for f in arrow.schema}),
        "pyarrow.dataset": (data.num_rows, {f.name: str(f.type) for f in data.schema}),
        "duckdb.read_parquet": (len(duck), {c: str(t) for c, t in zip(duck.columns, duck.dtypes,
                                                                     strict=True)}),
    }
    if polars:
        eager, lazy = pl.read_parquet(s), pl.scan_parquet(s).collect()
        seen["polars.read_parquet"] = (eager.height, {c: str(t) for c, t in eager.schema.items()})
        seen["polars.scan_parquet"] = (lazy.height, {c: str(t) for c, t in lazy.schema.items()})
    return seen


def _assert_agree(path: Path, seen: dict[str, tuple[int, dict[str, str]]]) -> None:
    """Same rows, columns and (by family) types in every reader; pandas as `PANDAS_ALSO`."""
    rows = {reader: n for reader, (n, _) in seen.items()}
    assert len(set(rows.values())) == 1, (path, rows)
    columns = {reader: list(t) for reader, (_, t) in seen.items()}
    assert all(c == columns["pyarrow.read_table"] for c in columns.values()), (path, columns)
    for col in columns["pyarrow.read_table"]:
        kinds = {reader: _kind(t[col]) for reader, (_, t) in seen.items()}
        want = kinds["pyarrow.read_table"]
        assert want in {*KINDS, "list"}, (path, col, kinds)
        others = {r: k for r, k in kinds.items() if r != "pandas"}
        assert set(others.values()) == {want}, (path, col, kinds)
        assert kinds["pandas"] in {want, *PANDAS_ALSO.get(want, set())}, (path, col, kinds)


def test_every_table_opens_in_every_reader_with_the_same_rows_and_types(
        cfg: M3GDConfig, tmp_path: Path) -> None:
    tables = _tables(cfg, tmp_path)
    names = {p.name for p in tables}
    assert {"view_stats", "cell_stats", "accuracy", "clips.parquet", "checks.parquet",
            "eval.parquet", "reprojection_consistency.parquet"} <= names
    for path in tables:  # polars on a table folder: the next test
        _assert_agree(path, _read_all(path, polars=path.is_file()))


def test_polars_opens_every_table_folder(cfg: M3GDConfig, tmp_path: Path) -> None:
    for path in [p for p in _tables(cfg, tmp_path) if p.is_dir()]:
        _assert_agree(path, _read_all(path))


def test_a_stats_folder_holds_one_file_per_recording_and_nothing_else(
        cfg: M3GDConfig) -> None:
    """Its checksum sidecars live beside the folder (polars refuses a folder with another
    kind of file in it)."""
    from schemas.atomic_io import check_file, checksum_path

    folder = cfg.layout.stats / "view_stats"
    assert [p.name for p in folder.iterdir()] == ["t_view.parquet"]
    sidecar = checksum_path(folder / "t_view.parquet")
    assert sidecar.parent == cfg.layout.stats / ".view_stats" and sidecar.exists()
    assert check_file(folder / "t_view.parquet") is None  # it matches
    assert not list(folder.glob("recording=*"))  # no hive folder
    assert pq.read_table(folder).schema.field("recording").type == pa.string()
    assert pd.read_parquet(folder)["recording"].unique().tolist() == ["t_view"]
