"""The errors m3gd raises on purpose, and which of them are permanent.

`DataError` (and its subclasses) is permanent: the item's input (a recording, a table, the
configuration, an argument) is wrong, so every try fails the same way; the executors report
it at once. Every other exception (an OSError, a lost worker, a library's race, a bug) may be
transient and is retried `dag.retries` times. Messages name the file, topic or array and the
stamp or row; a library error caught at a boundary is chained (`raise DataError(...) from err`).

Each class also derives from the built-in exception that code and callers caught before
(ValueError, FileNotFoundError, LookupError), so `except ValueError` keeps working.
"""

from __future__ import annotations


class M3GDError(Exception):
    """Base of every error m3gd raises on purpose."""


class DataError(M3GDError, ValueError):
    """Permanent: bad input data, configuration or argument; retrying cannot help."""


class MissingInputError(DataError, FileNotFoundError):
    """Permanent: a file or folder the item reads does not exist."""


class MissingDataError(DataError, LookupError):
    """Permanent: a record the item looks up (a message, a stamp) is not in its input."""
