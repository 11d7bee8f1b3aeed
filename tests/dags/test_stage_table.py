"""The stage table (`schemas.stages`) and its binding (`dags.graph`): every consumer follows
the table, and the table agrees with what the stages do."""

from __future__ import annotations

import dataclasses

from dags.graph import BINDINGS, STAGES, bind
from pipeline.cache.verify import SHARD_MARKED
from pipeline.run.checksums import GROUP_WRITER
from pipeline.run.stage import topological
from pipeline.stages.common import cache_key, upstream_key
from schemas import stages as table
from schemas.cache_layout import layout_arrays, writer_stage
from schemas.config import parse_config
from schemas.recording_index import INDEX_TABLES


def test_the_graph_binds_every_row_of_the_table_in_its_order() -> None:
    assert [s.name for s in STAGES] == list(table.STAGE_ORDER)
    assert set(BINDINGS) == set(table.STAGE_ORDER)
    for stage, spec in zip(STAGES, table.STAGE_TABLE, strict=True):
        assert (stage.depends, stage.unit) == (spec.depends, spec.unit)
    assert [s.name for s in topological(STAGES)] == list(table.STAGE_ORDER)


def test_every_dependency_is_a_row_listed_before_its_dependant() -> None:
    seen: set[str] = set()
    for spec in table.STAGE_TABLE:
        assert set(spec.depends) <= seen, spec.name
        seen.add(spec.name)


def test_each_cache_array_has_the_writer_its_row_declares() -> None:
    for spec in layout_arrays(with_h=True):
        row = table.writer_of_array(spec.name)
        assert row is not None and spec.writer_stage == row.name, spec.name
    assert writer_stage("latents_l3") == table.ENCODE.name
    assert writer_stage("latents_lx") is None and writer_stage("nope") is None
    declared = {a for s in table.STAGE_TABLE for a in s.arrays} - {table.LATENT_PREFIX}
    assert declared == {s.name for s in layout_arrays(with_h=True)} - {"latents_l0"}


def test_every_index_table_has_one_writer_row() -> None:
    for name in [*INDEX_TABLES, "selection", "selection_lidars"]:
        rows = [s.name for s in table.STAGE_TABLE if name in s.tables]
        assert len(rows) == 1, (name, rows)


def test_verify_and_checksums_derive_their_stages_from_the_table() -> None:
    assert (table.ENCODE.name, table.PACKETS.name) == SHARD_MARKED
    assert table.INGEST.name == GROUP_WRITER
    root = table.writer_of_root_attr("latent_norm")
    assert root is not None and root.name == table.STATS.name


def test_upstream_sections_are_what_the_upstream_key_hashes() -> None:
    cfg = parse_config({"output_dir": "/tmp/x", "ingest": {"recordings": []}})
    sections = [getattr(cfg, s) for s in table.upstream_sections()]
    assert cache_key(*sections) == upstream_key(cfg)
    changed = cfg.model_copy(update={"select": cfg.select.model_copy(
        update={"max_abs_dt_s": cfg.select.max_abs_dt_s / 2})})
    assert cache_key(*[getattr(changed, s) for s in table.upstream_sections()]) \
        == upstream_key(changed) != upstream_key(cfg)


def test_the_empty_recording_check_follows_the_row_that_declares_it() -> None:
    assert table.with_check(table.PostCheck.EMPTY_RECORDINGS) == (table.SELECT.name,)
    assert table.with_check(table.PostCheck.GEOMETRY_VERDICT) == (table.GEOMETRY.name,)


def test_a_new_row_binds_with_its_declared_name_dependencies_and_unit() -> None:
    extra = dataclasses.replace(table.CLIPS, name="extra", depends=(table.CLIPS.name,))
    stage = bind(extra, BINDINGS["clips"].plan, BINDINGS["clips"].run, BINDINGS["clips"].store)
    assert (stage.name, stage.depends, stage.unit) == ("extra", ("clips",), extra.unit)
