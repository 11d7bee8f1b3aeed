"""Stage, benchmark and report commands of the `m3gd` CLI (registered on the app)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Attach every implemented command to `app`."""
