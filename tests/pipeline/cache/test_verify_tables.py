"""`m3gd verify` and `m3gd run` over a damaged cache group `zarr.json` and a truncated run
manifest: one line each, never a traceback, and the rerun equals a clean run."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from bench.fuzz_repair import differing, digests, make_recording, raw_config, run_all
from cli.app import app
from schemas.config import parse_config

pytestmark = pytest.mark.slow
NO_GEOMETRY = {"geometry": {"enabled": False}}
"""The geometry table records its wall time, which no rerun reproduces (left out here)."""


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A finished tiny output and its raw config."""
    root = tmp_path_factory.mktemp("tables")
    raw = {**raw_config(root / "clean", make_recording(root / "recordings")), **NO_GEOMETRY}
    assert run_all(parse_config(raw)) == []
    return root / "clean", raw


def _case(clean: tuple[Path, dict[str, Any]], tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the clean output and a config file pointing at it."""
    out = tmp_path / "case"
    shutil.copytree(clean[0], out)
    cfg = tmp_path / "m3gd.yaml"
    cfg.write_text(yaml.safe_dump({**clean[1], "output_dir": str(out)}))
    return out, cfg


def _one_line_error(output: str) -> str:
    assert "Traceback" not in output and "JSONDecodeError" not in output, output
    lines = [line for line in output.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, output
    return lines[0]


def test_a_damaged_group_zarr_json_is_named_and_rebuilt(
        clean: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    """Was: verify passed and run ended in a JSONDecodeError traceback."""
    out, cfg = _case(clean, tmp_path)
    meta = out / "cache.zarr" / "m_repair" / "front" / "zarr.json"
    meta.write_bytes(meta.read_bytes()[:100])
    result = CliRunner().invoke(app, ["verify", str(out)])
    assert result.exit_code == 1, result.output
    text = result.output.replace("\n", "")
    assert f"{meta}: cut or grown" in text and "written by ingest m_repair" in text
    assert "redo: ingest m_repair" in text and "Traceback" not in text
    again = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert again.exit_code == 0, again.output
    assert differing(digests(clean[0]), digests(out)) == []


def test_a_run_over_a_damaged_group_zarr_json_redoes_it_without_verify(
        clean: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    out, cfg = _case(clean, tmp_path)
    meta = out / "cache.zarr" / "m_repair" / "front" / "zarr.json"
    data = bytearray(meta.read_bytes())
    data[data.index(b"n_views") + 10] ^= 1  # a changed digit: still JSON
    meta.write_bytes(bytes(data))
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert result.exit_code == 0, result.output
    assert differing(digests(clean[0]), digests(out)) == []


def test_a_truncated_manifest_is_one_line_and_verify_rebuilds_it(
        clean: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    """Was: a JSONDecodeError traceback from both verify and run, with no way on but
    deleting the manifest."""
    out, cfg = _case(clean, tmp_path)
    manifest = out / "manifest.json"
    manifest.write_bytes(manifest.read_bytes()[:200])
    run = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert run.exit_code != 0
    line = _one_line_error(run.output.replace("\n", " ").replace("error:", "\nerror:"))
    assert "manifest.json" in line and f"m3gd verify {out}" in line.replace(" \n", "")
    verify = CliRunner().invoke(app, ["verify", str(out)])
    assert verify.exit_code == 1 and "Traceback" not in verify.output, verify.output
    assert "set aside as" in verify.output.replace("\n", "")
    assert (out / "manifest.json.damaged").exists() and not manifest.exists()
    again = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert again.exit_code == 0, again.output
    (out / "manifest.json.damaged").unlink()
    assert differing(digests(clean[0]), digests(out)) == []
    assert CliRunner().invoke(app, ["verify", str(out)]).exit_code == 0


META = ("zarr.json", "m_repair/zarr.json", "m_repair/front/valid/zarr.json",
        "m_repair/front/latents_l0/zarr.json", "m_repair/front/h_cells/zarr.json",
        "m_repair/front/K/zarr.json")
"""Cache metadata files of every kind: the root, a recording group, an array of each
writer stage (select, encode, packets, ingest)."""
WRITERS = {"zarr.json": "stats _latent_norm", "m_repair/zarr.json": "ingest m_repair",
           "m_repair/front/valid/zarr.json": "select m_repair",
           "m_repair/front/latents_l0/zarr.json": "encode m_repair (camera front)",
           "m_repair/front/h_cells/zarr.json": "packets m_repair (camera front)",
           "m_repair/front/K/zarr.json": "ingest m_repair"}


@pytest.mark.parametrize("rel", META)
def test_a_garbled_cache_zarr_json_is_named_with_its_writer_and_redone_exactly(
        clean: tuple[Path, dict[str, Any]], tmp_path: Path, rel: str) -> None:
    """Was: verify ended in a JSONDecodeError traceback (arrays, the root; `run` refused a
    garbled root with 'rm -r'), or passed and `run` said up to date (a recording group)."""
    out, cfg = _case(clean, tmp_path)
    meta = out / "cache.zarr" / rel
    meta.write_bytes(meta.read_bytes()[:60])
    result = CliRunner().invoke(app, ["verify", str(out)])
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    text = result.output.replace("\n", "")
    assert f"{meta}: " in text and f"written by {WRITERS[rel]}" in text, text
    again = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert again.exit_code == 0, again.output
    assert differing(digests(clean[0]), digests(out)) == []
    assert CliRunner().invoke(app, ["verify", str(out)]).exit_code == 0


@pytest.mark.parametrize("rel", ["zarr.json", "m_repair/front/g/zarr.json"])
def test_a_run_without_verify_repairs_garbled_cache_metadata(
        clean: tuple[Path, dict[str, Any]], tmp_path: Path, rel: str) -> None:
    out, cfg = _case(clean, tmp_path)
    meta = out / "cache.zarr" / rel
    meta.write_bytes(meta.read_bytes()[:-30])
    result = CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"])
    assert result.exit_code == 0 and "Traceback" not in result.output, result.output
    assert differing(digests(clean[0]), digests(out)) == []


def test_a_flipped_digit_of_the_latent_norm_is_found_by_its_sidecar(
        clean: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    """Was: the root's `latent_norm` was written without a checksum: a changed digit that
    still parses passed `verify` and was trained on."""
    out, cfg = _case(clean, tmp_path)
    root = out / "cache.zarr" / "zarr.json"
    data = bytearray(root.read_bytes())
    at = data.index(b'"mean"') + 12
    while not chr(data[at]).isdigit():
        at += 1
    data[at] = ord("1") if data[at] != ord("1") else ord("2")
    root.write_bytes(bytes(data))
    result = CliRunner().invoke(app, ["verify", str(out)])
    text = result.output.replace("\n", "")
    assert result.exit_code == 1 and f"{root}: CRC32C mismatch" in text, text
    assert "written by stats _latent_norm" in text
    assert CliRunner().invoke(app, ["-c", str(cfg), "run", "--local"]).exit_code == 0
    assert differing(digests(clean[0]), digests(out)) == []
