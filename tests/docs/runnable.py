"""Runnable blocks of the guides: a fenced shell block right after `<!-- runnable -->`."""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"
MARKER = "<!-- runnable -->"
_BLOCK = re.compile(re.escape(MARKER) + r"\s*\n```(?:bash|sh|shell)\n(.*?)\n```", re.S)
_ANY_MARKER = re.compile(re.escape(MARKER))


def runnable_blocks(page: Path) -> list[str]:
    """The shell source of every runnable block of `page`, in order.

    Raises ValueError when a marker is not followed by a shell block (a marker that would
    silently run nothing)."""
    text = page.read_text()
    blocks = _BLOCK.findall(text)
    markers = len(_ANY_MARKER.findall(text))
    if markers != len(blocks):
        raise ValueError(f"{page}: {markers} runnable markers but {len(blocks)} shell blocks "
                         "right after one")
    return blocks


def guide(name: str) -> Path:
    """The guide page `docs/guides/<name>.md`."""
    return DOCS / "guides" / f"{name}.md"
