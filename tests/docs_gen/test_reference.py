"""The generated reference pages: complete (every key, table, array, command) and true (the
documented formulas and packing checked against the code that writes the cache)."""

from __future__ import annotations

import math

import numpy as np
from typer.main import get_command

from cli.app import app
from docs_gen import cache_ref, cli_ref, config_ref, tables_ref
from model.evaluate import BASELINES, REPROJ_CANDIDATES
from packets.statistics import CHANNELS, CellStats, explicit_channels
from schemas import recording_index as ri
from schemas.cache_layout import LatentNorm
from schemas.config import M3GDConfig
from schemas.packed_cells import pack_rows
from schemas.tables import ALL_TABLES, eval_targets_schema


def test_configuration_page_lists_every_key_with_its_description() -> None:
    page = config_ref.render()
    keys = config_ref.every_key()
    assert len(keys) > 100
    for key in keys:
        assert f"| `{key}` |" in page, key
    assert "| `train.steps` | int | `8000` |" in page
    assert "| `synth.format` | \"rosbag\" \\| \"hf-zarr\" | `\"rosbag\"` |" in page


def test_tables_page_lists_every_schema_and_column() -> None:
    page = tables_ref.render()
    schemas = {**ALL_TABLES, **ri.INDEX_TABLES, "selection": ri.SELECTION,
               "selection_lidars": ri.SELECTION_LIDARS,
               "eval_targets": eval_targets_schema(BASELINES, REPROJ_CANDIDATES)}
    assert {name for name, *_ in tables_ref.TABLES} == set(schemas)
    for name, schema in schemas.items():
        assert f"## `{name}`" in page
        for field in schema:
            assert f"| `{field.name}` | `{field.type}` |" in page, (name, field.name)
    for reason in ri.Reason:
        assert f"- `{reason.value}`" in page


def test_cache_page_lists_every_array_with_dtype_and_chunks() -> None:
    page = cache_ref.render()
    cfg = M3GDConfig()
    for spec in cache_ref.default_arrays(cfg):
        row = next(line for line in page.splitlines() if line.startswith(f"| `{spec.name}` |"))
        assert f"`{spec.dtype}`" in row and f"`{spec.chunks(cfg.cache.shard_views)}`" in row
    for k, name in enumerate(CHANNELS):
        assert f"| {k} | `{name}` |" in page
    assert ('"latent_norm": {"mean": [C floats], "std": [C floats], "count": cells, '
            '"views": valid views, "groups": {"<recording>/<camera>": valid views}}') in page


def test_cache_page_documents_every_field_the_stats_stage_writes_in_latent_norm() -> None:
    """Was: the page showed mean, std and count only, not the view counts per group that the
    trainer checks the cache against."""
    page = cache_ref.render()
    section = page[page.index("## Latent normalization"):page.index("## Attributes")]
    on_disk = LatentNorm([0.5], [2.0], 12, {"r/front": 3, "r/left": 1}).to_attrs()
    documented = [line.split("`")[1] for line in section.splitlines()
                  if line.startswith("| `")]
    assert documented == list(on_disk)
    assert on_disk["views"] == 4 and "--force stats" in section


def test_documented_g_channels_are_what_the_code_computes() -> None:
    n, mean, var, dtau = 3, 2.0, 0.5, 0.0125  # one occupied cell, one empty
    stats = CellStats(n=np.array([n, 0]), mean=np.array([mean, 0.0]), var=np.array([var, 0.0]))
    g = explicit_channels(stats, dtau, (1, 2))
    documented = [1.0, math.log(1 + mean), 1 / mean, math.log(1 + n), var, dtau]
    np.testing.assert_allclose(g[:, 0, 0], documented, rtol=1e-6)
    assert not g[:, 0, 1].any()  # an empty cell is zero in every channel


def test_documented_h_unpacking_rebuilds_dense_h() -> None:
    rng = np.random.default_rng(0)
    h_dense = rng.normal(size=(1, 5, 3, 4)).astype(np.float32)  # (N, C_u, H, W)
    occ = rng.random((1, 3, 4)) < 0.5
    h_dense *= occ[:, None]
    (rows,) = pack_rows(h_dense, occ)
    h_cells = np.zeros((12, 5), np.float32)  # (H*W, C_u): packed rows, then zeros
    h_cells[: len(rows)] = rows
    g0 = occ[0].astype(np.float32)
    # the snippet of the cache page, verbatim in substance
    mask = g0 > 0.5
    k = int(mask.sum())
    h = np.zeros((3, 4, 5), h_cells.dtype)
    h[mask] = h_cells[:k]
    np.testing.assert_array_equal(h, np.moveaxis(h_dense[0], 0, -1))


def test_cli_page_has_every_command() -> None:
    page = cli_ref.render()
    paths = [p for p, _ in cli_ref.commands()]
    assert len(paths) > 30
    for path in paths:
        assert f"`{' '.join(path)}`" in page
    root = get_command(app)
    assert {p[1] for p in paths if len(p) == 2} == set(root.commands)  # type: ignore[attr-defined]


def test_conventions_page_lists_every_convention_of_the_table() -> None:
    from docs_gen import conventions_ref
    from schemas.time_conventions import CONVENTIONS, DRIVERS

    page = conventions_ref.render()
    assert all(f"`time_{c.name}`" in page for c in CONVENTIONS)
    assert all(name in page for name in DRIVERS)
    assert "| float32 | ns | absolute |" in page  # listed among those not held
