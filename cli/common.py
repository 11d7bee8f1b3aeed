"""Shared CLI state: the loaded configuration, logging, errors that exit cleanly, printing."""

from __future__ import annotations

import json
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import typer
from rich.console import Console, ConsoleDimensions
from rich.logging import RichHandler
from rich.table import Table
from rich.text import Text

from schemas.config import ConfigError, M3GDConfig, load_config

if TYPE_CHECKING:
    import pyarrow as pa

WIDE = 4096
"""Width of a console that does not write to a terminal: tables keep every column whole."""


class PlainConsole(Console):
    """A rich console that never cuts a table when it writes to a file or a pipe.

    On a terminal it is rich's console. Elsewhere its width is WIDE instead of 80 columns (or
    the width of whichever standard stream is a terminal), so `m3gd stats summary | less` and
    `m3gd eval > eval.out` keep full cells; an explicit width (tests) is kept.
    """

    @property
    def size(self) -> ConsoleDimensions:
        """Terminal size on a terminal; WIDE columns elsewhere."""
        dims = Console.size.fget(self)  # type: ignore[attr-defined]
        if self.is_terminal or self._width is not None:
            return dims  # type: ignore[no-any-return]
        return ConsoleDimensions(WIDE, dims.height)

    @size.setter
    def size(self, new_size: tuple[int, int]) -> None:
        Console.size.fset(self, new_size)  # type: ignore[attr-defined]

    def render_str(self, text: str, **kwargs: Any) -> Text:
        """`text` as it is: never parsed as console markup or emoji codes, its control
        characters written as escapes (`visible`). Every string printed (a `print` argument,
        a table cell, a title) passes here; styles come from `styled` instead of markup."""
        kwargs.update(markup=False, emoji=False)
        return super().render_str(visible(text), **kwargs)


def visible(text: str) -> str:
    """`text` with every character that is not printable, newline apart (control characters
    such as ESC or tab, bidirectional marks, a lone surrogate), written as its Python escape
    (`\\x1b`, `\\t`, `\\u202e`): a string from data cannot move the cursor, recolour the
    terminal or reorder the line it is printed in, and prints as it is."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() or ch == "\n" else ascii(ch)[1:-1] for ch in text)


def styled(*parts: str | tuple[str, str]) -> Text:
    """One line of `parts`, each printed as it is (`visible`, never parsed as markup); a
    `(text, style)` pair is styled (`styled(("error:", "bold red"), " ", message)`)."""
    return Text.assemble(*(visible(p) if isinstance(p, str) else (visible(p[0]), p[1])
                           for p in parts))


def write_json(data: Any, indent: int | None = 2) -> None:
    """`data` as JSON on standard output, written as it is (never through the console's
    renderer): every string round-trips, non-ASCII and control characters as JSON escapes;
    values JSON cannot hold (dates, decimals) as their text."""
    sys.stdout.write(json.dumps(data, default=str, indent=indent) + "\n")
    sys.stdout.flush()


console = PlainConsole(stderr=True)
stdout = PlainConsole()


@dataclass
class CliState:
    """What the top-level options set: config path and verbosity."""

    config_path: Path | None = None
    verbosity: int = 0


def setup_logging(verbosity: int) -> None:
    """Configure logging: -q warnings only, default info, -v debug. On a terminal rich's
    handler; elsewhere plain lines (`time LEVEL message`, never wrapped)."""
    level = {-1: logging.WARNING, 0: logging.INFO}.get(verbosity, logging.DEBUG)
    handler: logging.Handler
    if console.is_terminal:
        handler = RichHandler(console=console, show_path=False, rich_tracebacks=False)
        fmt = "%(message)s"
    else:
        handler = logging.StreamHandler()  # the sys.stderr of this invocation
        fmt = "%(asctime)s %(levelname)s %(message)s"
    logging.basicConfig(level=level, format=fmt, handlers=[handler], force=True)
    for noisy in ("distributed", "numcodecs", "matplotlib", "PIL", "botocore", "boto3"):
        logging.getLogger(noisy).setLevel(max(level, logging.WARNING))


def fail(message: str, code: int = 1) -> NoReturn:
    """Print one error line and exit with `code`."""
    console.print(styled(("error:", "bold red"), " ", one_line(message)), soft_wrap=True)
    raise typer.Exit(code)


def write_failed(err: OSError, what: str) -> NoReturn:
    """Exit 1 with one line for a write that failed (a full disk, a read-only folder, no
    permission): the file, the reason, what was not written and what to do."""
    reason = err.strerror or str(err).splitlines()[0] or type(err).__name__
    where = f"{err.filename}: " if err.filename else ""
    fail(f"{where}{reason}; the {what} not written (free space or make the folder writable, "
         "then run the same command again)")


def one_line(message: str) -> str:
    """`message` itself, or for an error re-raised from a DataLoader worker (torch puts the
    worker's traceback into the message) the worker's own error line without its class."""
    if "Original Traceback" not in message:
        return message
    last = [line for line in message.splitlines() if line.strip()][-1]
    name, sep, rest = last.partition(": ")
    return rest if sep and name.replace(".", "").replace("_", "").isalnum() else last


def local_output(output_dir: Path, command: str, needs: str = "", given: bool = False) -> None:
    """Exit 2 with one line when `command` cannot work on an `s3://` output_dir (unless
    `given`: the options `needs` names were passed)."""
    from pipeline.run.remote import LocalOnly, refuse_on_store

    if given:
        return
    try:
        refuse_on_store(output_dir, command, needs)
    except LocalOnly as err:
        fail(str(err), 2)


def state(ctx: typer.Context) -> CliState:
    """The CliState stored by the top-level callback."""
    root = ctx.find_root()
    if not isinstance(root.obj, CliState):
        root.obj = CliState()
    return root.obj


def config_of(ctx: typer.Context) -> M3GDConfig:
    """Load and validate the configuration; exit 2 with one line when it is bad."""
    try:
        return load_config(state(ctx).config_path)
    except ConfigError as err:
        fail(str(err), code=2)


def emit(result: dict[str, Any], as_json: bool, title: str) -> None:
    """Print a flat result dict as JSON or as a rich table."""
    if as_json:
        write_json(result)
        return
    table = Table(title=title)
    table.add_column("figure")
    table.add_column("value", justify="right")
    for key, value in result.items():
        text = f"{value:.4g}" if isinstance(value, float) else str(value)
        table.add_row(key, text)
    stdout.print(table)


def duplicate_columns(names: list[str]) -> list[str]:
    """The names that occur more than once in `names`, in order of their second occurrence
    (a JSON object holds one value per name: the later one would silently replace the
    earlier)."""
    seen: set[str] = set()
    dupes: list[str] = []
    for name in names:
        if name in seen and name not in dupes:
            dupes.append(name)
        seen.add(name)
    return dupes


def refuse_duplicate_columns(names: list[str]) -> None:
    """Exit 2 with one line naming the first duplicated column of a result printed as JSON
    (nothing printed before): objects cannot hold both values."""
    dupes = duplicate_columns(names)
    if dupes:
        fail(f"--json: the result has {names.count(dupes[0])} columns named {dupes[0]!r}, and "
             "a JSON object holds one value per name; give them distinct names (AS ...)", 2)


def print_arrow(table: pa.Table, as_json: bool) -> None:
    """Print an Arrow table as JSON lines (`write_json`, one object per row) or a rich table
    (numbers right-aligned). JSON of a table with duplicated column names is refused
    (`refuse_duplicate_columns`), never printed with a value dropped."""
    if as_json:
        refuse_duplicate_columns(table.column_names)
        for row in table.to_pylist():
            write_json(row, indent=None)
        return
    stdout.print(arrow_table(table))


def arrow_table(table: pa.Table) -> Table:
    """A rich table of an Arrow table: cells as text (floats to 4 significant digits),
    numeric columns right-aligned."""
    import pyarrow as pa

    out = Table()
    for field in table.schema:
        numeric = pa.types.is_integer(field.type) or pa.types.is_floating(field.type) \
            or pa.types.is_decimal(field.type)
        out.add_column(field.name, justify="right" if numeric else "left")
    for row in zip(*(column.to_pylist() for column in table.columns), strict=True):
        out.add_row(*(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row))
    return out


def refuse_foreign_output(path: Path, cfg: M3GDConfig, what: str,
                          ours: Callable[[Path], bool]) -> None:  # fmt: skip
    """Exit 2 with one line when `path`, where `what` is about to be written, lies inside the
    cache store or is an existing file or folder that m3gd did not write (`ours` says)."""
    cache = cfg.layout.cache.resolve()
    target = path.resolve()
    if target == cache or cache in target.parents:
        fail(f"{path}: inside the cache store {cfg.layout.cache}; write the {what} elsewhere", 2)
    if target.exists() and not ours(target):
        kind = "folder" if target.is_dir() else "file"
        fail(f"{path}: an existing {kind} that m3gd did not write; choose another path for the "
             f"{what} or remove it", 2)


def checkpoint_folder(path: Path) -> bool:
    """Whether `path` is a folder a checkpoint may be written into: empty, or one holding a
    checkpoint (`model.checkpoint.has_checkpoint`), its metrics log or the temporary of a
    killed save (a run stopped before its first checkpoint)."""
    from model.checkpoint import has_checkpoint, temporaries

    return path.is_dir() and (not any(path.iterdir()) or has_checkpoint(path)
                              or (path / "metrics.jsonl").exists() or bool(temporaries(path)))


def rerun_file(path: Path) -> bool:
    """Whether `path` is a Rerun recording (its file starts with the RRF magic)."""
    if not path.is_file():
        return False
    with path.open("rb") as f:
        return f.read(3) == b"RRF"


def check_threads(n: int) -> None:
    """Exit 2 with one line when `n` torch threads exceed `max_threads()` (a huge count
    crashed inside OpenMP)."""
    import os

    cpus = os.cpu_count() or 1
    if n > max_threads(cpus):
        fail(f"--threads {n}: more than {max_threads(cpus)} (4 per CPU of this machine's "
             f"{cpus}, at least 64)", 2)


def max_threads(cpus: int) -> int:
    """The most torch threads m3gd starts on a machine of `cpus` CPUs."""
    return max(64, 4 * cpus)
