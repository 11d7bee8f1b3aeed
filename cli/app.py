"""The `m3gd` command line, assembled: every command group and command in one place.

The commands are plain module-level functions in one module per group (`cli.stages`,
`cli.stats`, `cli.analysis`, `cli.model`, `cli.bench`, `cli.config`); this module alone
attaches them to the Typer app, in the order `m3gd --help` lists them. Nothing registers
itself on import.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from cli import analysis, bench, model, stages, stats, view
from cli import config as config_commands
from cli import inspect as inspect_command
from cli.common import setup_logging, state

HELP = "Camera-LiDAR recordings to M3GD training caches, plus trainer and sampler."


def package_version() -> str:
    """The installed m3gd's version (package metadata; pyproject.toml's `version`)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("m3gd")
    except PackageNotFoundError:  # a checkout on PYTHONPATH without an install
        return "unknown (not installed: pip install -e .)"


def _print_version(value: bool) -> None:
    """`--version`: print `m3gd <version>` and exit."""
    if value:
        typer.echo(f"m3gd {package_version()}")
        raise typer.Exit()


def short_help(command: Callable[..., Any]) -> str:
    """A command's first sentence, whole: the line `m3gd --help` lists (click would cut it
    at the terminal's width with `...`; this text is wrapped instead)."""
    first = " ".join((command.__doc__ or "").strip().split("\n\n")[0].split())
    end = re.search(r"(?<!e\.g)(?<!i\.e)\. ", first)
    return first if end is None else first[:end.start() + 1]


def main(
    ctx: typer.Context,
    config: Annotated[
        Path | None, typer.Option("--config", "-c", help="YAML configuration file.")
    ] = None,
    verbose: Annotated[int, typer.Option("--verbose", "-v", count=True, help="More log.")] = 0,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Warnings and errors only.")] = False,
    version: Annotated[bool, typer.Option(  # handled by its callback
        "--version", callback=_print_version, is_eager=True,
        help="Print the m3gd version and exit.")] = False,
) -> None:
    """m3gd: staged preprocessing of GrandTour recordings into M3GD caches."""
    st = state(ctx)
    st.config_path = config
    st.verbosity = -1 if quiet else verbose
    setup_logging(st.verbosity)


def _group(help_text: str, commands: dict[str, Callable[..., Any]]) -> typer.Typer:
    """A command group holding `commands` (name -> function), in that order."""
    group = typer.Typer(help=help_text, no_args_is_help=True, rich_markup_mode=None)
    for name, command in commands.items():
        group.command(name, short_help=short_help(command))(command)
    return group


def build() -> typer.Typer:
    """The `m3gd` app with every command group and command attached. Help is click's plain
    layout (flags without a `<bool>` type, wrapped at the terminal's width)."""
    root = typer.Typer(name="m3gd", help=HELP, no_args_is_help=True,
                       pretty_exceptions_enable=False, add_completion=False,
                       rich_markup_mode=None)
    root.callback()(main)
    root.add_typer(_group(config_commands.HELP, {"show": config_commands.show}),
                   name="config")
    root.add_typer(_group(stats.HELP, {"query": stats.query, "summary": stats.summary}),
                   name="stats")
    commands: dict[str, Callable[..., Any]] = {
        "run": stages.run, "demo": stages.demo, "unlock": stages.unlock,
        "verify": stages.verify, "synth": stages.synth,
        "ingest": stages.ingest, "select": stages.select,
        "plot": analysis.plot, "accuracy": analysis.accuracy, "align": analysis.align,
        "train": model.train, "sample": model.sample, "eval": model.evaluate,
        "view": view.view, "report": view.report,
        "inspect": inspect_command.inspect,
    }
    for name, command in commands.items():
        root.command(name, short_help=short_help(command))(command)
    root.add_typer(_group(bench.HELP, {
        "cache": bench.cache, "packets": bench.packets, "ingest": bench.ingest,
        "packing": bench.packing, "dag": bench.dag, "synth": bench.synth, "costs": bench.costs,
        "fuzz": bench.fuzz, "variants": bench.variants,
        "storage": bench.storage,
        "sampler": bench.sampler, "loader": bench.loader,
        "tradeoffs": bench.tradeoffs, "view": bench.view,
        "science": bench.science, "ddp": bench.ddp,
    }), name="bench")
    return root


app = build()

if __name__ == "__main__":
    app()
