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
