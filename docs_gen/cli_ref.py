"""The command-line reference: every `m3gd` command, its arguments and options, from the
Typer app (`cli.app.app`) through click's introspection."""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from typing import Any

import typer.main

from cli.app import app


def commands(group: Any = None,
             path: tuple[str, ...] = ("m3gd",)) -> Iterator[tuple[tuple[str, ...], Any]]:
    """(name path, command) of every command and group, in `--help` order, depth first.

    Commands are Typer's click commands (duck-typed: a group has `commands`)."""
    group = group or typer.main.get_command(app)
    yield path, group
    for name, cmd in group.commands.items():
        if hasattr(cmd, "commands"):
            yield from commands(cmd, (*path, name))
        else:
            yield (*path, name), cmd


def _text(text: str) -> str:
    """Help text as Markdown: `<` and `>` escaped outside code spans (`<output_dir>` would be
    read as an HTML tag)."""
    parts = text.split("`")
    for i in range(0, len(parts), 2):  # even parts lie outside backticks
        parts[i] = parts[i].replace("<", "&lt;").replace(">", "&gt;")
    return "`".join(parts)


def _code(text: str) -> str:
    """An option's synopsis for a code span in a table cell."""
    return " ".join(text.split()).replace("|", "\\|")


def _cell(text: str) -> str:
    return _text(" ".join(text.split())).replace("|", "\\|")


def _section(path: tuple[str, ...], cmd: Any) -> list[str]:
    ctx = cmd.context_class(cmd, info_name=" ".join(path))
    level = "#" * min(len(path) + 1, 4)
    out = [f"{level} `{' '.join(path)}`", "", _text(inspect.cleandoc(cmd.help or "")), ""]
    usage = cmd.get_usage(ctx).removeprefix("Usage: ")
    out += ["```text", usage, "```", ""]
    rows = []
    for param in cmd.params:
        record = param.get_help_record(ctx)
        if param.param_type_name == "argument":
            help_text = getattr(param, "help", None) or ""
            rows.append((param.name.upper(), help_text or "(argument)"))
        elif record is not None:
            rows.append((record[0], record[1]))
    if rows:
        out += ["| argument or option | meaning |", "|---|---|"]
        out += [f"| `{_code(a)}` | {_cell(b)} |" for a, b in rows]
        out.append("")
    return out


def render() -> str:
    """The CLI reference page (Markdown)."""
    out = ["# Command line", "",
           "Generated from the Typer app (`cli/app.py`) each time the site is built: what "
           "`m3gd <command> --help` prints. Top-level options (`-c/--config FILE`, `-v`, "
           "`-q`) come before the command: `m3gd -c my.yaml run`.", ""]
    for path, cmd in commands():
        out += _section(path, cmd)
    return "\n".join(out)
