"""Runnable blocks of the guides: a fenced shell or Python block right after
`<!-- runnable -->` (a Python block runs as `python -` in the same shell script, so the page
highlights it as Python)."""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"
MARKER = "<!-- runnable -->"
_BLOCK = re.compile(re.escape(MARKER) + r"\s*\n```(bash|sh|shell|python)\n(.*?)\n```", re.S)
_HEREDOC_END = "M3GD_PYTHON_BLOCK_END"
_ANY_MARKER = re.compile(re.escape(MARKER))


def runnable_blocks(page: Path) -> list[str]:
    """The shell source of every runnable block of `page`, in order (a Python block wrapped as
    `python - <<'END' ... END`).

    Raises ValueError when a marker is not followed by a shell or Python block (a marker that
    would silently run nothing)."""
    text = page.read_text()
    found = _BLOCK.findall(text)
    markers = len(_ANY_MARKER.findall(text))
    if markers != len(found):
        raise ValueError(f"{page}: {markers} runnable markers but {len(found)} shell blocks "
                         "right after one")
    return [f"python - <<'{_HEREDOC_END}'\n{code}\n{_HEREDOC_END}" if lang == "python"
            else code for lang, code in found]


def guide(name: str) -> Path:
    """The guide page `docs/guides/<name>.md` (`reference/python_api` for that page)."""
    if "/" in name:
        return DOCS / f"{name}.md"
    return DOCS / "guides" / f"{name}.md"
