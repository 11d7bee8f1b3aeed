"""The `m3gd` command line, assembled: every command group and command in one place.

The commands are plain module-level functions in one module per group (`cli.stages`,
`cli.stats`, `cli.analysis`, `cli.model`, `cli.config`); this module alone attaches them to the
Typer app, in the order `m3gd --help` lists them. Nothing registers itself on import. Groups
that live beside the product (the benchmarks, `m3gd bench`) are found through the entry point
group `m3gd.commands` of the installed distributions and attached last, so the product never
imports them.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Iterable
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Annotated, Any

import typer

from cli import analysis, model, stages, stats, view
from cli import config as config_commands
from cli import inspect as inspect_command
from cli.common import setup_logging, state

HELP = "Camera-LiDAR recordings to M3GD training caches, plus trainer and sampler."
COMMAND_GROUPS = "m3gd.commands"
"""Entry point group of the command groups installed beside the product: each entry point names
a `(help, {name: command})` pair and is attached as `m3gd <entry point name> ...`."""


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
    root.add_typer(_group(stats.HELP, {"query": stats.query, "summary": stats.summary,
                                           "export": stats.export}),
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
    for name, (help_text, group) in installed_groups(entry_points(group=COMMAND_GROUPS)).items():
        root.add_typer(_group(help_text, group), name=name)
    return root


def installed_groups(
    points: Iterable[EntryPoint],
) -> dict[str, tuple[str, dict[str, Callable[..., Any]]]]:
    """The command groups the entry points name, by entry point name (sorted). One that does not
    load is left out with a one-line note on stderr naming it and why: the product's commands
    stay usable when a group beside it is broken or half installed."""
    groups: dict[str, tuple[str, dict[str, Callable[..., Any]]]] = {}
    for point in sorted(points, key=lambda p: p.name):
        try:
            help_text, commands = point.load()
        except (ImportError, AttributeError, TypeError, ValueError) as exc:
            print(f"m3gd: command group {point.name!r} ({point.value}, entry point group "
                  f"{COMMAND_GROUPS}) not attached: {type(exc).__name__}: {exc}",
                  file=sys.stderr)
            continue
        groups[point.name] = (help_text, commands)
    return groups


app = build()

if __name__ == "__main__":
    app()
