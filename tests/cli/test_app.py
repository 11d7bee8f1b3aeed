"""The assembled app (cli.app): `--version` from package metadata, help readable at 80 columns."""

from __future__ import annotations

from importlib.metadata import version

import pytest
from typer.main import get_command
from typer.testing import CliRunner

from cli.app import app, short_help
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
