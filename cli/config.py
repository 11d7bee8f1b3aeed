"""`m3gd config ...`: inspect the configuration."""

from __future__ import annotations

import inspect
from typing import Annotated, Any

import typer
import yaml
from pydantic import BaseModel

from cli.common import config_of, stdout
from schemas.config import config_to_dict

HELP = "Inspect the configuration."


def _scalar(value: Any) -> str:
    """A value as one line of YAML flow style."""
    text = str(yaml.safe_dump(value, default_flow_style=True, width=10**6))
    return text.strip().removesuffix("\n...").removesuffix("...").strip()


def documented_yaml(model: BaseModel, data: dict[str, Any], indent: int = 0) -> list[str]:
    """YAML lines of `data` (the dump of `model`), each section and key preceded by its
    description as a comment."""
    pad = " " * indent
    lines: list[str] = []
    fields = type(model).model_fields
    for key, value in data.items():
        field = fields[key]
        sub = getattr(model, key)
        if isinstance(sub, BaseModel):
            doc = inspect.cleandoc(type(sub).__doc__ or "").splitlines()[0]
            lines += [f"{pad}# {doc}", f"{pad}{key}:"]
            lines += documented_yaml(sub, value, indent + 2)
            continue
        if field.description:
            lines.append(f"{pad}# {field.description}")
        lines.append(f"{pad}{key}: {_scalar(value)}")
    return lines


def show(ctx: typer.Context, doc: Annotated[bool, typer.Option(
        "--doc", help="Each key with its description as a YAML comment.")] = False) -> None:
    """Print the effective configuration (defaults filled in) as YAML."""
    cfg = config_of(ctx)
    if doc:
        stdout.print("\n".join(documented_yaml(cfg, config_to_dict(cfg))), highlight=False,
                     markup=False, soft_wrap=True)
        return
    stdout.print(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), end="", highlight=False)
