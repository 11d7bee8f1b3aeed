"""The repair loop of `m3gd bench fuzz` and its config-change figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.fuzz_repair import (
    CONFIG_CHANGES,
    make_recording,
    raw_config,
    run_all,
    run_repair,
    stale_after_changes,
)
from schemas.config import parse_config


def test_a_config_change_recomputes_every_derived_artefact(tmp_path: Path) -> None:
    """Was: `encoders.image_channels` and `cache.shard_views` changed on a finished output:
    stats failed on every rerun (the old layout's latent parts were merged: shapes (32,) and
    (768,)); `shard_views` alone: latent_norm silently over more views than the cache holds."""
    raw = raw_config(tmp_path / "clean", make_recording(tmp_path / "recordings"))
    assert run_all(parse_config(raw)) == []
    change = "image_channels+shard_views"
    stale = stale_after_changes(tmp_path, raw, {change: CONFIG_CHANGES[change]})
    assert stale == {change: []}
    norm = json.loads((tmp_path / "changed" / "cache.zarr" / "zarr.json").read_text())[
        "attributes"]["latent_norm"]
    assert len(norm["mean"]) == 32 and norm["views"] == sum(norm["groups"].values()) > 0
    parts = sorted(p.name for p in (tmp_path / "changed" / "stats" / "latent_parts").rglob("*"))
    assert parts == sorted(p.name for p in (tmp_path / "fresh" / "stats" / "latent_parts")
                           .rglob("*"))  # fmt: skip


@pytest.mark.slow
def test_repair_figures(tmp_path: Path) -> None:
    figures = run_repair(tmp_path)
    assert figures["repair_rounds"] == 11
    for key in ("repair_not_detected", "repair_still_damaged", "repair_not_identical",
                "arrays_lost_by_repair", "repair_failed_items",
                "stale_derived_after_config_change"):
        assert figures[key] == 0, (key, figures["repair_failures"])
