"""`m3gd align` over a tiny cache: identical features give 1, planted relations beat the null,
sparse and invalid views are handled, the table is written and read back."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from packets.alignment import METRICS
from pipeline.analysis.align import image_features, run_alignment, write_alignment
from schemas.cache_layout import GridSpec
from schemas.tables import ALIGNMENT, read_table
from tests.model.cache_fixture import N, build_cache

GRID = GridSpec(14 * 4, 14 * 6)  # 4 x 6 = 24 cells
CH = 8
Arrays = dict[str, np.ndarray]


def _supported(arrays: Arrays, rng: np.random.Generator, n_cells: int) -> None:
    """Mark `n_cells` random cells of every view supported (g[0] = 1) and every view valid."""
    arrays["valid"][:] = True
    g = arrays["g"]
    for v in range(len(g)):
        cells = rng.choice(GRID.grid_h * GRID.grid_w, n_cells, replace=False)
        g[v, 0].flat[cells] = 1.0
        g[v, 1].flat[cells] = rng.uniform(0.5, 3.0, n_cells)


def _f16(x: np.ndarray) -> np.ndarray:
    """Round to float16-representable float32 values (h is stored as float16)."""
    return x.astype(np.float16).astype(np.float32)


def _cache(tmp: Path, fill: Callable[[np.random.Generator, Arrays], None],
           cameras: tuple[str, ...] = ("front",)) -> Path:
    rng = np.random.default_rng(7)
    def fill_supported(rec: str, cam: str, arrays: Arrays) -> None:
        fill(rng, arrays)
        arrays["h"] *= arrays["g"][:, :1] == 1.0  # eq. 10: no features on unsupported cells

    build_cache(tmp, ("r0",), cameras, grid=GRID, channels=(CH, CH), fill=fill_supported)
    return tmp


def _rows(table: object) -> dict[str, dict[str, float]]:
    return {r["metric"]: r for r in table.to_pylist()}  # type: ignore[attr-defined]


def test_identical_features_give_one_for_every_metric(tmp_path: Path) -> None:
    def fill(rng: np.random.Generator, a: Arrays) -> None:
        _supported(a, rng, 12)
        a["latents_l0"][:] = _f16(rng.standard_normal(a["latents_l0"].shape))
        # h equals the latents on supported cells and is 0 elsewhere (the latents are not):
        # only the supported cells may be compared
        a["h"][:] = a["latents_l0"]

    out = _cache(tmp_path, fill)
    table = run_alignment(out, [("latents_l0", "h")], n_perm=5)
    rows = _rows(table)
    assert sorted(rows) == sorted(METRICS)
    for name, row in rows.items():
        assert row["value"] == pytest.approx(1.0, abs=1e-9), name
        assert row["null_value"] < 0.9, name
        assert row["images"] == N and row["excluded_images"] == 0
        assert row["pair"] == "latents_l0:h"


def test_planted_relation_beats_the_null_and_independent_features_do_not(tmp_path: Path) -> None:
    mix = np.random.default_rng(1).standard_normal((CH, CH))

    def fill(rng: np.random.Generator, a: Arrays) -> None:
        _supported(a, rng, 20)
        lat = rng.standard_normal(a["latents_l0"].shape)                   # (N, C, H, W)
        a["latents_l0"][:] = lat
        planted = np.tanh(np.einsum("dc,nchw->ndhw", mix, lat) / 2)        # (N, C_u, H, W)
        a["h"][:] = planted + 0.2 * rng.standard_normal(planted.shape)
        # 'g' vs 'h' has no planted relation: g[1] is independent of h

    out = _cache(tmp_path, fill, ("front", "left"))
    table = run_alignment(out, [("latents_l0", "h"), ("g", "h")], n_perm=10, seed=3)
    by_pair: dict[str, dict[str, dict[str, float]]] = {}
    for r in table.to_pylist():
        by_pair.setdefault(r["pair"], {})[r["metric"]] = r
    for name, row in by_pair["latents_l0:h"].items():
        assert row["value"] > row["null_value"] + 0.1, (name, row)
        assert row["images"] == 2 * N
    for name, row in by_pair["g:h"].items():
        assert abs(row["value"] - row["null_value"]) < 0.1, (name, row)


def test_sparse_and_invalid_views_are_excluded_and_counted(tmp_path: Path) -> None:
    def fill(rng: np.random.Generator, a: Arrays) -> None:
        _supported(a, rng, 10)
        a["latents_l0"][:] = rng.standard_normal(a["latents_l0"].shape)
        a["h"][:] = rng.standard_normal(a["h"].shape)
        a["g"][:4] = 0.0
        a["g"][0, 0, 0, :2] = 1.0   # 2 supported cells
        a["g"][1, 0, 1, 0] = 1.0    # 1 supported cell; views 2, 3: none
        a["valid"][4:7] = False     # well-supported but invalid: never read as images

    out = _cache(tmp_path, fill)
    rows = _rows(run_alignment(out, [("latents_l0", "h")], n_perm=2))
    for row in rows.values():
        assert row["excluded_images"] == 4
        assert row["images"] == N - 4 - 3
    sizes = [x.shape[0] for x, _ in image_features(out, ("latents_l0", "h"))]
    assert sizes == [2, 1, 0, 0] + [10] * (N - 7)

    limited = _rows(run_alignment(out, [("latents_l0", "h")], n_perm=2, max_images=6))
    assert limited["cka"]["images"] == 2 and limited["cka"]["excluded_images"] == 4


def test_table_round_trip_and_bad_inputs(tmp_path: Path) -> None:
    def fill(rng: np.random.Generator, a: Arrays) -> None:
        _supported(a, rng, 6)
        a["latents_l0"][:] = rng.standard_normal(a["latents_l0"].shape)
        a["h"][:] = rng.standard_normal(a["h"].shape)

    out = _cache(tmp_path, fill)
    table = run_alignment(out, [("latents_l0", "h")], n_perm=3, max_images=5)
    path = write_alignment(out, table)
    assert path == out / "stats" / "alignment.parquet"
    assert read_table(path, ALIGNMENT).equals(table.cast(ALIGNMENT))
    again = run_alignment(out, [("latents_l0", "h")], n_perm=3, max_images=5)
    assert again.equals(table)  # seeded null: reproducible
    with pytest.raises(ValueError, match="latents_x"):
        run_alignment(out, [("latents_x", "h")])
    with pytest.raises(FileNotFoundError, match="latents_l1"):
        run_alignment(out, [("latents_l1", "h")])
    with pytest.raises(FileNotFoundError, match="no m3gd cache"):
        run_alignment(tmp_path / "elsewhere", [("latents_l0", "h")])


def test_cli_refuses_to_write_a_table_when_no_view_has_enough_cells(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cli.app import app

    out = _cache(tmp_path, lambda rng, a: _supported(a, rng, 2))  # 2 < --min-cells 3
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {out}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "align", "--n-perm", "2"])
    assert result.exit_code == 1
    assert "no view has >= 3 supported cells" in result.output
    assert f"({N} excluded)" in result.output
    assert not (out / "stats" / "alignment.parquet").exists()
