"""The strict base every config section derives from, and what sections share: scene and
camera names, the camera-name check, the device pattern, dropping unset keys when serialized
(so that adding a key leaves the hashes of configs that leave it unset unchanged)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict

from schemas.errors import DataError
from schemas.names import check_name

SceneName = Literal["corridor", "warehouse", "forest", "plaza"]
CameraName = Literal["front", "left", "right"]
"""The default cameras (GrandTour's HDR triple, which the `{camera}` templates name). Not a
constraint: `ingest.cameras` and `synth.cameras` take any names (`check_camera_names`)."""


def scene_list(*names: SceneName) -> list[SceneName]:
    """A typed list of scene names (a default factory)."""
    return list(names)


def camera_list(*names: str) -> list[str]:
    """A typed list of camera names (a default factory)."""
    return list(names)


def check_camera_names(names: list[str], key: str) -> None:
    """Camera names become group and file names of the outputs: each a valid path component,
    none twice (DataError naming `key`)."""
    for name in names:
        check_name(name, f"{key}: camera name")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise DataError(f"{key}: camera {twice[0]!r} is listed twice")


def drop_empty(data: dict[str, object], *keys: str) -> dict[str, object]:
    """`data` without the empty optional `keys`: a config that leaves them unset serializes
    (and hashes, so keys its caches) as before they existed."""
    return {k: v for k, v in data.items() if not (k in keys and is_empty(v))}


def is_empty(value: object) -> bool:
    """Unset: falsy, or a sequence of zeros (an offset of (0, 0, 0))."""
    return not value or (isinstance(value, (list, tuple)) and not any(value))


DEVICE_PATTERN = r"^(auto|cpu|mps|cuda(:[0-9]+)?)$"
"""auto (CUDA when available, else CPU), cpu, cuda, cuda:N, mps."""


class StrictModel(BaseModel):
    """Base for config sections: unknown keys and type coercions are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    not_in_key: ClassVar[frozenset[str]] = frozenset()
    """Fields that say where or how work runs, not what it computes: left out of cache keys."""


SensorVariant = str
"""A synthetic sensor variant's name: a key of `pipeline.synth.variants.VARIANTS`, assembled
from its groups (the point-time group derives from `schemas.time_conventions`); an unknown name
is refused by synth in one line listing the known ones."""
