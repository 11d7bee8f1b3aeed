"""Input checks shared by the packet math: shapes, finiteness, named errors."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from schemas.errors import DataError


def require_finite(name: str, values: npt.ArrayLike) -> None:
    """Raise ValueError naming `name`, the first bad index and its value on any NaN/Inf."""
    arr = np.asarray(values)
    if arr.size == 0 or not np.issubdtype(arr.dtype, np.inexact):
        return
    finite = np.isfinite(arr)
    if bool(finite.all()):
        return
    bad = int(np.flatnonzero(~finite.ravel())[0])
    pos = np.unravel_index(bad, arr.shape)
    raise DataError(
        f"{name} has {int((~finite).sum())} non-finite value(s); first at index "
        f"{tuple(int(p) for p in pos)} = {arr.ravel()[bad]!r}"
    )


def require_shape(name: str, arr: Any, shape: tuple[int | None, ...]) -> None:
    """Raise ValueError unless `arr.shape` matches `shape` (None matches any length)."""
    got = tuple(arr.shape)
    same = len(got) == len(shape)
    ok = same and all(s is None or s == g for s, g in zip(shape, got, strict=True))
    if not ok:
        want = tuple("*" if s is None else s for s in shape)
        raise DataError(f"{name} must have shape {want}, got {got}")


def require_finite_scalar(name: str, value: float) -> float:
    """Return `value` as float, raising ValueError if it is NaN or Inf."""
    out = float(value)
    if not np.isfinite(out):
        raise DataError(f"{name} must be finite, got {value!r}")
    return out
