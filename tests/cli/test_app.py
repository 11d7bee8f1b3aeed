"""The assembled app (cli.app): `--version` from package metadata, help readable at 80 columns."""

from __future__ import annotations

import tomllib
from importlib.metadata import EntryPoint, entry_points, version
from pathlib import Path

import pytest
from typer.main import get_command
from typer.testing import CliRunner

from cli.app import COMMAND_GROUPS, app, installed_groups, short_help
from tests.cli.test_cli import _paths


def test_version_is_the_package_metadata_version() -> None:
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0, result.output
    assert result.output == f"m3gd {version('m3gd')}\n"


@pytest.mark.parametrize("path", _paths(get_command(app)))
def test_help_fits_80_columns_and_shows_no_bool_type(path: tuple[str, ...]) -> None:
    result = CliRunner().invoke(app, [*path, "--help"], terminal_width=80,
                                env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    assert "<bool>" not in result.output
    listed = result.output.partition("Commands:")[2]
    assert "..." not in listed  # no listed command's line cut
    wide = [line for line in result.output.splitlines() if len(line) > 80]
    # a literal \b block (the table list of `stats query`) is kept as written
    assert all(line.startswith("    ") for line in wide), wide


def test_short_help_is_the_whole_first_sentence() -> None:
    def cmd() -> None:
        """Remove a lock (e.g. on another host). More text.

        Second paragraph."""

    assert short_help(cmd) == "Remove a lock (e.g. on another host)."


def _hello() -> None:
    """Say hello."""


FAKE_GROUP = ("A group beside the product.", {"hello": _hello})


def test_groups_beside_the_product_attach_and_a_broken_one_is_named(
        capsys: pytest.CaptureFixture[str]) -> None:
    points = [EntryPoint("zz", "tests.cli.test_app:FAKE_GROUP", COMMAND_GROUPS),
              EntryPoint("broken", "no_such_module_m3gd:GROUP", COMMAND_GROUPS)]
    assert installed_groups(points) == {"zz": FAKE_GROUP}
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "'broken' (no_such_module_m3gd:GROUP" in err and "ModuleNotFoundError" in err


def test_bench_is_beside_the_product_not_in_its_wheel() -> None:
    """m3gd's wheel lists no bench package; `m3gd bench` comes from m3gd-bench's entry point."""
    root = Path(__file__).resolve().parents[2]
    setuptools = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert not any(p.startswith("bench") for p in setuptools["packages"]["find"]["include"])
    [point] = [p for p in entry_points(group=COMMAND_GROUPS) if p.name == "bench"]
    assert point.value == "bench.cli:GROUP" and point.dist is not None
    assert point.dist.name == "m3gd-bench"
