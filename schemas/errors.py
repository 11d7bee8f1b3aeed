"""The errors m3gd raises on purpose, and which of them are permanent.

`DataError` (and its subclasses) is permanent: the item's input (a recording, a table, the
configuration, an argument) is wrong, so every try fails the same way; the executors report
it at once. Every other exception (an OSError, a lost worker, a library's race, a bug) may be
transient and is retried `dag.retries` times. Messages name the file, topic or array and the
stamp or row; a library error caught at a boundary is chained (`raise DataError(...) from err`).

Each class also derives from the built-in exception that code and callers caught before
(ValueError, FileNotFoundError, LookupError), so `except ValueError` keeps working.

Every class survives pickling unchanged (type, message, attributes), whichever executor carries
it: plain pickle, cloudpickle, and dask.distributed's serialization (which reduces exceptions
with tblib, and whose default rebuild calls `cls.__new__`: for a class mixing a ValueError with
a FileNotFoundError that resolves to `ValueError.__new__`, which Python refuses for an
OSError-shaped instance). `M3GDError.__reduce__` rebuilds through `_rebuild` instead, which
neither calls a subclass's own `__init__` (whose parameters need not be the message) nor a
`__new__` of the wrong memory layout.
"""

from __future__ import annotations

from typing import Any


def _layout_base(cls: type[BaseException]) -> type[BaseException]:
    """The built-in exception class whose memory layout `cls` instances have (`__base__` chain:
    the layout base, not the first class of the MRO)."""
    base: type[BaseException] = cls
    while base.__flags__ & (1 << 9):  # Py_TPFLAGS_HEAPTYPE: a class defined in Python
        base = base.__base__  # type: ignore[assignment]  # never None below BaseException
    return base


def _rebuild(cls: type[BaseException], args: tuple[Any, ...],
             state: dict[str, Any]) -> BaseException:
    """An instance of `cls` with `args` and attributes `state`, without calling its __init__."""
    err = _layout_base(cls).__new__(cls, *args)
    err.args = args
    err.__dict__.update(state)
    return err


class M3GDError(Exception):
    """Base of every error m3gd raises on purpose."""

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle as (class, args, attributes), rebuilt by `_rebuild` (see the module doc)."""
        return (_rebuild, (type(self), self.args, dict(self.__dict__)))


class DataError(M3GDError, ValueError):
    """Permanent: bad input data, configuration or argument; retrying cannot help."""


class MissingInputError(DataError, FileNotFoundError):
    """Permanent: a file or folder the item reads does not exist."""


class MissingDataError(DataError, LookupError):
    """Permanent: a record the item looks up (a message, a stamp) is not in its input."""
