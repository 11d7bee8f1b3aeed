"""Model commands of the `m3gd` CLI: train, sample, eval, bench sampler, bench loader."""

from __future__ import annotations

import typer


def register_model(app: typer.Typer, bench: typer.Typer) -> None:
    """Attach `train`, `sample`, `eval` to `app` and `sampler`, `loader` to `bench`."""
