"""Names that become path components under an output root: mission and recording names.

A recording name is a folder under `index/`, a group under `cache.zarr/` and a partition of the
statistics; a synthetic mission name is a folder under the synth output. Such a name must stay
inside its root and be a valid Zarr node name that collides with none of the store's own files
(`zarr.json`, `manifest.json`, names starting with `.`): `check_name` refuses anything else, in
one line.
"""

from __future__ import annotations

from schemas.errors import DataError

MAX_NAME = 200
"""Longest name accepted (file systems allow 255 bytes; the index adds suffixes)."""
RESERVED = frozenset({"zarr.json", "manifest.json"})
"""Names of files the product writes beside a group's children: a child of that name would turn
the group's metadata into a folder (a camera named `zarr.json` did, and the run exited 0)."""


def name_problem(name: str) -> str | None:
    """Why `name` cannot be a path component under a root (None when it can)."""
    if not name or name in (".", ".."):
        return "is empty, '.' or '..'"
    if "/" in name or "\\" in name:
        return "contains a path separator ('/' or '\\'); give a plain folder name"
    if name.startswith("__"):
        return "starts with '__', which Zarr reserves"
    if name in RESERVED:
        return f"is the name of a file the store writes beside it ({name!r})"
    if name.startswith("."):
        return "starts with '.', which the store keeps for its own hidden files"
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        return "contains a control character"
    if name.strip() != name:
        return "starts or ends with white space"
    if len(name.encode()) > MAX_NAME:
        return f"is longer than {MAX_NAME} bytes"
    return None


def check_name(name: str, what: str) -> str:
    """`name` if it can be a path component under a root; DataError naming `what` otherwise."""
    problem = name_problem(name)
    if problem is not None:
        raise DataError(f"{what} {name!r} {problem}")
    return name
