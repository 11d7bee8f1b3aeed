"""The configuration reference: every key of `schemas.config.M3GDConfig`, as Markdown.

One section per config section, one table row per key: dotted key, type, default and the
field's `description`. Nested sections (`ingest.topics`, ...) get their own section.
"""

from __future__ import annotations

import inspect
import json
import typing
from collections.abc import Iterator
from typing import Any

from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from schemas.config import M3GDConfig


def type_name(annotation: Any) -> str:
    """A short readable name of a field's type (`list[corridor | warehouse]`, `int | None`)."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Literal:
        return " \\| ".join(json.dumps(a) if isinstance(a, str) else str(a) for a in args)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " \\| ".join(type_name(a) for a in args)
    if origin is list:
        return f"list[{type_name(args[0])}]"
    if origin is dict:
        return f"dict[{type_name(args[0])}, {type_name(args[1])}]"
    if annotation is type(None):
        return "null"
    if isinstance(annotation, type):
        return "path" if annotation.__name__.endswith("Path") else annotation.__name__
    alias = getattr(annotation, "__value__", None)  # a `type X = ...` alias
    return type_name(alias) if alias is not None else str(annotation)


def default_text(field: FieldInfo) -> str:
    """The default as it would appear in YAML (`config show`)."""
    if field.default_factory is not None:
        value = field.default_factory()  # type: ignore[call-arg]
    elif field.default is PydanticUndefined:
        return "(required)"
    else:
        value = field.default
    if isinstance(value, BaseModel):
        return "(section)"
    if value is None:
        return "`null`"
    return f"`{json.dumps(value, default=str)}`"


def bounds_text(field: FieldInfo) -> str:
    """Numeric bounds of a field (`> 0, ≤ 3600`), or ''."""
    parts = []
    for meta in field.metadata:
        for attr, sign in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
            value = getattr(meta, attr, None)
            if value is not None:
                parts.append(f"{sign} {value}")
    return ", ".join(parts)


def _is_section(annotation: Any) -> bool:
    return inspect.isclass(annotation) and issubclass(annotation, BaseModel)


def sections(model: type[BaseModel] = M3GDConfig,
             prefix: str = "") -> Iterator[tuple[str, type[BaseModel]]]:
    """(dotted path, model) of `model` and every nested section, depth first."""
    yield prefix, model
    for name, field in model.model_fields.items():
        if _is_section(field.annotation):
            yield from sections(field.annotation, f"{prefix}{name}.")  # type: ignore[arg-type]


def key_rows(model: type[BaseModel], prefix: str) -> list[tuple[str, str, str, str]]:
    """(key, type, default, description) of every plain key of one section."""
    rows = []
    for name, field in model.model_fields.items():
        if _is_section(field.annotation):
            continue
        desc = field.description or ""
        bounds = bounds_text(field)
        if bounds:
            desc = f"{desc} ({bounds})" if desc else f"({bounds})"
        rows.append((f"{prefix}{name}", type_name(field.annotation), default_text(field),
                     desc.replace("|", "\\|")))
    return rows


def every_key() -> list[str]:
    """Every dotted key of the configuration (sections excluded)."""
    return [row[0] for path, model in sections() for row in key_rows(model, path)]


def _doc(model: type[BaseModel]) -> str:
    return inspect.cleandoc(model.__doc__ or "").replace("\n\n", "\n\n")


def render() -> str:
    """The configuration reference page (Markdown)."""
    out = [
        "# Configuration reference",
        "",
        "Generated from `schemas/config.py` (the pydantic models) each time the site is built.",
        "A configuration is YAML; every key is optional (the defaults below apply) and an unknown",
        "key or a bad value stops the command with one line naming the file, the key and the",
        "value (every bad key at once, with a did-you-mean). `m3gd config show` prints the",
        "effective configuration, `m3gd config show --doc` the same with these descriptions.",
        "",
    ]
    for path, model in sections():
        title = path.rstrip(".") or "top level"
        out += [f"## `{title}`" if path else "## Top level", "", _doc(model), ""]
        rows = key_rows(model, path)
        if not rows:
            continue
        out += ["| key | type | default | description |", "|---|---|---|---|"]
        out += [f"| `{k}` | {t} | {d} | {s} |" for k, t, d, s in rows]
        out.append("")
    return "\n".join(out)
