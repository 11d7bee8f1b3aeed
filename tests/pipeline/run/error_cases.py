"""Every error class m3gd raises on purpose, and one instance of each (for transport tests).

Imported by value onto Dask workers (`cloudpickle.register_pickle_by_value`), so the workers
need nothing from tests/.
"""

from __future__ import annotations

import importlib
import pkgutil
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from schemas.errors import M3GDError

PACKAGES = ("schemas", "packets", "model", "pipeline", "dags", "cli")


def _subclasses(cls: type[M3GDError]) -> Iterator[type[M3GDError]]:
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


def error_classes() -> list[type[M3GDError]]:
    """M3GDError and every subclass defined anywhere in the project's packages."""
    for pkg in PACKAGES:
        module = importlib.import_module(pkg)
        for info in pkgutil.walk_packages(module.__path__, f"{pkg}."):
            if not info.name.endswith("__main__"):  # `python -m cli` would run the app
                importlib.import_module(info.name)
    found = [M3GDError, *_subclasses(M3GDError)]
    return sorted(set(found), key=lambda c: f"{c.__module__}.{c.__qualname__}")


def class_name(cls: type) -> str:
    """`module:qualname` of a class."""
    return f"{cls.__module__}:{cls.__qualname__}"


def sample(name: str) -> M3GDError:
    """One instance of the class `module:qualname`, raised with a cause (as m3gd raises)."""
    module, qualname = name.split(":")
    cls = getattr(importlib.import_module(module), qualname)
    try:
        try:
            raise KeyError("/topic")
        except KeyError as cause:
            raise _build(cls) from cause
    except M3GDError as err:
        return err


def _build(cls: type[M3GDError]) -> M3GDError:
    """An instance of `cls`: the classes with their own __init__ get their own arguments."""
    from model.loop import TrainingDiverged
    from model.train_step import DivergedError
    from pipeline.ingest.errors import RowReject
    from schemas.manifest import ManifestDamaged
    from schemas.recording_index import Reason

    message = f"/data/m/a.bag: /topic: stamp 1700000000123456789 ns: {cls.__name__}"
    if cls is RowReject:
        return RowReject(Reason.UNDECODABLE_MESSAGE, "/data/m/a.bag", message)
    if cls is DivergedError:
        return DivergedError(7, "loss", float("inf"))
    if cls is ManifestDamaged:
        return ManifestDamaged(Path("/data/out/manifest.json"), "cut at byte 12 of 340")
    if cls is TrainingDiverged:
        return TrainingDiverged(DivergedError(7, "loss", float("nan")), 0.25, None)
    return cls(message)


def raise_sample(name: str) -> None:
    """Raise `sample(name)` (run on a worker)."""
    raise sample(name)


def same(a: BaseException, b: BaseException) -> bool:
    """Same class, message, args and attributes."""
    return (type(a) is type(b) and str(a) == str(b) and a.args == b.args
            and _attrs(a) == _attrs(b))


def _attrs(err: BaseException) -> dict[str, Any]:
    """The instance attributes; float NaN made comparable."""
    return {k: ("nan" if isinstance(v, float) and v != v else v) for k, v in vars(err).items()}


class UnpicklableCause(Exception):
    """A library's exception that cannot be pickled (it holds a lock)."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.lock = threading.Lock()
