"""Text is data: strings from data, paths, SQL results and errors are printed as they are
(never parsed as console markup or emoji codes, control characters escaped), and `--json`
is written without the console's renderer, every value round-tripping."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import pyarrow as pa
import pytest
import typer
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console
from typer.testing import CliRunner

from cli.app import app
from cli.common import fail, print_arrow, stdout, styled, visible
from tests.pipeline.analysis.test_query import _output

MARKUP = ["[red]abc", "[nan, 1.0]", "[/x]", "a[/]b", "[link=http://x]y[/link]", "b[",
          "[draft]", ":memory:", ":red_circle:", "[bold]x[/bold]", "\\[x]"]
TRICKY = st.text(st.characters(codec="utf-8"), max_size=30) | st.sampled_from(
    [*MARKUP, "\x1b[31mred", "rtl\u202egnp.exe", "\u200f\u200e", "line\nbreak", "\r", "a\tb"])
"""Strings a recording, a path or a SQL result may hold (Arrow strings are UTF-8: no lone
surrogate; `visible` escapes one, tested apart)."""


def _query(tmp_path: Path, *args: str) -> tuple[int, str]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {_output(tmp_path / 'out')}\n")
    result = CliRunner().invoke(app, ["-c", str(cfg), "stats", "query", *args])
    return result.exit_code, result.output


def _printed(table: pa.Table, as_json: bool) -> str:
    buffer = io.StringIO()
    with redirect_stdout(buffer):
        print_arrow(table, as_json)
    return buffer.getvalue()


@settings(max_examples=60, deadline=None)
@given(st.lists(TRICKY, min_size=1, max_size=5))
def test_json_lines_round_trip_every_string(values: list[str]) -> None:
    table = pa.table({"v": values, "n": list(range(len(values)))})
    lines = _printed(table, True).splitlines()
    assert [json.loads(line) for line in lines] == table.to_pylist()


@settings(max_examples=40, deadline=None)
@given(st.lists(TRICKY.filter(lambda s: "\n" not in s), min_size=1, max_size=3))
def test_table_cells_are_printed_as_they_are(values: list[str]) -> None:
    text = _printed(pa.table({"v": values}), False)
    for value in values:
        assert visible(value) in text
    assert "\x1b" not in text and "\u202e" not in text


@settings(max_examples=60, deadline=None)
@given(TRICKY)
def test_an_error_line_prints_its_message_as_it_is(message: str) -> None:
    console = Console(file=io.StringIO(), width=10**5)
    console.print(styled(("error:", "bold red"), " ", message), soft_wrap=True)
    assert console.file.getvalue() == f"error: {visible(message)}\n"  # type: ignore[attr-defined]


def test_visible_escapes_only_what_is_not_printable() -> None:
    assert visible("[red]a b:smile:c\nd") == "[red]a b:smile:c\nd"
    assert visible("a\x1bb\u202ec\ud800\t") == "a\\x1bb\\u202ec\\ud800\\t"


def test_query_json_keeps_markup_like_values(tmp_path: Path) -> None:
    sql = "SELECT " + ", ".join(f"'{v}' AS c{i}" for i, v in enumerate(MARKUP))
    code, text = _query(tmp_path, "--json", sql)
    assert code == 0, text
    assert json.loads(text) == {f"c{i}": v for i, v in enumerate(MARKUP)}


def test_query_table_prints_markup_like_values(tmp_path: Path) -> None:
    sql = "SELECT " + ", ".join(f"'{v}' AS c{i}" for i, v in enumerate(MARKUP))
    code, text = _query(tmp_path, sql)
    assert code == 0, text
    for value in MARKUP:
        assert value in text


def test_markup_in_an_error_and_a_column_name(tmp_path: Path) -> None:
    code, text = _query(tmp_path, 'SELECT 1 AS "[/x]", 2 AS "[draft]"')
    assert code == 0 and "[/x]" in text and "[draft]" in text, text
    code, text = _query(tmp_path, 'SELECT * FROM "b[/x]"')
    assert code == 1 and "b[/x]" in text and len(text.strip().splitlines()) == 1, text


def test_numbers_are_right_aligned(tmp_path: Path) -> None:
    code, text = _query(tmp_path, "SELECT 7 AS number, 'x' AS word UNION ALL "
                        "SELECT 12345, 'longer' ORDER BY 1")
    rows = [line for line in text.splitlines() if " 7 " in line or "longer" in line]
    assert code == 0 and len(rows) == 2, text
    seven, big = rows
    assert seven.index("7") == big.index("12345") + 4  # right edges aligned
    assert seven.index("x") == big.index("longer")  # words left-aligned


def test_fail_prints_a_bracketed_folder_name(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(typer.Exit):
        fail("/data/[draft]/b[/run: not a folder")
    assert capsys.readouterr().err.strip() == "error: /data/[draft]/b[/run: not a folder"


def test_the_consoles_parse_no_markup(capsys: pytest.CaptureFixture[str]) -> None:
    stdout.print("[bold]x[/] :smile: [/]")
    assert capsys.readouterr().out.strip() == "[bold]x[/] :smile: [/]"
