"""HTML building blocks of the report, as pure functions of values (no file access).

Every string from the data is escaped; images are embedded as data URIs; the page carries a
Content-Security-Policy that forbids any fetch (no server, no network: the page is complete on
its own).
"""

from __future__ import annotations

import base64
import html
import math
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import pyarrow as pa

CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
STYLE = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#1d1d1f;
background:#fff;line-height:1.4}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.5em 0 1.5em;font-size:.9em}
div.tw{max-width:100%;overflow-x:auto}
th,td{border:1px solid #ddd;padding:.25em .6em;text-align:right}
th{background:#f2f4f7;overflow-wrap:normal;word-break:normal;hyphens:none}
td.s{overflow-wrap:anywhere}td.s,th.s{text-align:left}caption{text-align:left;font-weight:600;
padding:.3em 0}p.note{color:#555;font-size:.9em}
div.groups{display:flex;flex-wrap:wrap;gap:0 2em;align-items:flex-start}
figure{display:inline-block;margin:.5em;width:calc(50% - 1.2em);vertical-align:top}
figure.wide{width:calc(100% - 1em)}figcaption{font-size:.9em;color:#333}
img{max-width:100%;border:1px solid #eee}nav a{margin-right:1em}
figure>a.zoom{cursor:zoom-in}figure a.close{display:none}
figure:target{position:fixed;inset:0;margin:0;width:auto;background:#fff;z-index:9;
overflow:auto;padding:1em;box-sizing:border-box}
figure:target>a.zoom{cursor:default}figure:target img{max-width:none}
figure:target a.close{display:block;position:sticky;top:0;left:0;background:#fff;
padding:.2em 0;font-weight:600}
details{margin:.5em 0 1em}summary{cursor:pointer;font-weight:600}
"""
"""Headers wrap only at spaces and at the <wbr> after underscores (never mid-word); wide
tables scroll inside their div; plots sit two to a row, a plot drawn wider than half the page
takes the whole row, and a click on a plot shows it at its drawn size over the page (the
figure becomes the URL's target: CSS only, no script)."""
HALF_PAGE_PX = 600
"""A PNG wider than this (half the page's 1200 px) is shown across the page's width."""


@dataclass(frozen=True)
class Section:
    """One part of the page: anchor id, heading and body HTML."""

    id: str
    title: str
    body: str


def esc(value: object) -> str:
    """HTML-escaped text of a value."""
    return html.escape(str(value), quote=True)


def cell_text(value: Any) -> str:
    """Display text of one table value: ints exact, floats to 6 significant digits, NaN/None
    as an empty cell, lists joined by commas."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(cell_text(v) for v in value)
    return str(value)


def header_html(name: str) -> str:
    """A column name, escaped, that may break after each underscore (`max_abs_dtau_ms` wraps
    to fit a narrow page instead of widening its table)."""
    return "_<wbr>".join(esc(part) for part in name.split("_"))


def _is_text(dtype: pa.DataType) -> bool:
    """Whether a column is left-aligned (strings, lists, dictionaries)."""
    return bool(pa.types.is_string(dtype) or pa.types.is_large_string(dtype)
                or pa.types.is_dictionary(dtype) or pa.types.is_list(dtype))


def table_html(table: pa.Table, table_id: str, caption: str = "",
               total_rows: int | None = None) -> str:
    """An Arrow table as an HTML table with id `table_id`; when `total_rows` exceeds the rows
    given, a note says how many were left out. A table without rows is one note
    (`caption: none`)."""
    if table.num_rows == 0 and not total_rows:  # a sentence, not an empty table
        return note(f"{caption}: none" if caption else "none")
    text_cols = [_is_text(f.type) for f in table.schema]
    head = "".join(f'<th class="{"s" if t else "n"}">{header_html(n)}</th>'
                   for n, t in zip(table.column_names, text_cols, strict=True))
    rows = []
    for row in table.to_pylist():
        cells = "".join(f'<td class="{"s" if t else "n"}">{esc(cell_text(v))}</td>'
                        for v, t in zip(row.values(), text_cols, strict=True))
        rows.append(f"<tr>{cells}</tr>")
    cap = f"<caption>{esc(caption)}</caption>" if caption else ""
    out = (f'<div class="tw"><table id="{esc(table_id)}">{cap}<thead><tr>{head}</tr></thead>'
           f'<tbody>{"".join(rows)}</tbody></table></div>')
    if total_rows is not None and total_rows > table.num_rows:
        out += note(f"first {table.num_rows} of {total_rows} rows shown")
    return out


def kv_table(pairs: Iterable[tuple[str, object]], table_id: str, caption: str = "") -> str:
    """A two-column (key, value) table."""
    items = list(pairs)
    return table_html(pa.table({"key": [k for k, _ in items],
                                "value": [cell_text(v) for _, v in items]}), table_id, caption)


def png_data_uri(png: bytes) -> str:
    """A PNG file's bytes as a data: URI."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def png_width(png: bytes) -> int:
    """Width in pixels of a PNG (its IHDR chunk); 0 when the bytes are not a PNG."""
    if len(png) < 24 or png[:8] != b"\x89PNG\r\n\x1a\n" or png[12:16] != b"IHDR":
        return 0
    return int.from_bytes(png[16:20], "big")


def figure(png: bytes, caption: str, name: str = "", wide: bool = False,
           back: str = "plots") -> str:
    """An embedded PNG with its caption (also its alt text); `name` (the file stem) is kept in
    a data attribute, not shown, and names the figure's anchor: a click on the image shows it
    at its drawn size over the page, `close` goes back to the section `back`. `wide`: the
    page's whole width instead of half (also when the PNG is wider than HALF_PAGE_PX)."""
    data = f' data-file="{esc(name)}"' if name else ""
    cls = ' class="wide"' if wide or png_width(png) > HALF_PAGE_PX else ""
    anchor = f"fig-{name or format(zlib.crc32(png), '08x')}"
    return (f'<figure id="{esc(anchor)}"{cls}><a class="close" href="#{esc(back)}">close</a>'
            f'<a class="zoom" href="#{esc(anchor)}"><img src="{png_data_uri(png)}" '
            f'alt="{esc(caption)}"{data}></a>'
            f"<figcaption>{esc(caption)}</figcaption></figure>")


def collapsed(summary: str, body: str, open_: bool = False) -> str:
    """`body` behind a <details> element whose always-visible line is `summary` (raw rows a
    reader opens on demand)."""
    return (f'<details{" open" if open_ else ""}><summary>{esc(summary)}</summary>{body}'
            "</details>")


def groups(parts: Iterable[str]) -> str:
    """Small tables side by side, wrapping to the next line when the page is narrow."""
    return f'<div class="groups">{"".join(parts)}</div>'


def note(text: str) -> str:
    """A small explanatory paragraph."""
    return f'<p class="note">{esc(text)}</p>'


def page(title: str, sections: Sequence[Section], subtitle: str = "") -> str:
    """The whole document: head with CSP and inline style, a contents bar, the sections."""
    nav = "".join(f'<a href="#{esc(s.id)}">{esc(s.title)}</a>' for s in sections)
    body = "".join(f'<section id="{esc(s.id)}"><h2>{esc(s.title)}</h2>{s.body}</section>'
                   for s in sections)
    sub = note(subtitle) if subtitle else ""
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f'<meta http-equiv="Content-Security-Policy" content="{CSP}">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<link rel="icon" href="data:,">'
            f"<title>{esc(title)}</title><style>{STYLE}</style></head>"
            f"<body><h1>{esc(title)}</h1>{sub}<nav>{nav}</nav>{body}</body></html>")
