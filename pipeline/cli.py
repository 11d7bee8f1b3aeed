"""The `m3gd` command line: one entry point for every stage, benchmark and report."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
import yaml

from pipeline.cli_common import config_of, setup_logging, state, stdout
from schemas.config import config_to_dict

app = typer.Typer(
    name="m3gd",
    help="Camera-LiDAR recordings to M3GD training caches, plus trainer and sampler.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
config_app = typer.Typer(help="Inspect the configuration.", no_args_is_help=True)
app.add_typer(config_app, name="config")


@app.callback()
def main(
    ctx: typer.Context,
    config: Annotated[
        Path | None, typer.Option("--config", "-c", help="YAML configuration file.")
    ] = None,
    verbose: Annotated[int, typer.Option("--verbose", "-v", count=True, help="More log.")] = 0,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Warnings and errors only.")] = False,
) -> None:
    """m3gd: staged preprocessing of GrandTour recordings into M3GD caches."""
    st = state(ctx)
    st.config_path = config
    st.verbosity = -1 if quiet else verbose
    setup_logging(st.verbosity)


@config_app.command("show")
def config_show(ctx: typer.Context) -> None:
    """Print the effective configuration (defaults filled in) as YAML."""
    cfg = config_of(ctx)
    stdout.print(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), end="", highlight=False)


def _register() -> None:
    """Attach the command groups defined in their own modules."""
    from pipeline import cli_commands

    cli_commands.register(app)


_register()


if __name__ == "__main__":
    app()
