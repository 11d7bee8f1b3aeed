"""`m3gd config ...`: inspect the configuration."""

from __future__ import annotations

import typer
import yaml

from cli.common import config_of, stdout
from schemas.config import config_to_dict

HELP = "Inspect the configuration."


def show(ctx: typer.Context) -> None:
    """Print the effective configuration (defaults filled in) as YAML."""
    cfg = config_of(ctx)
    stdout.print(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), end="", highlight=False)
