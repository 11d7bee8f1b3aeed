"""Format versions of every on-disk artifact, and the refusal of unknown ones."""

from __future__ import annotations

from schemas.errors import DataError

VERSION_KEY = "m3gd_format_version"
KIND_KEY = "m3gd_kind"


class UnknownSchemaVersion(DataError):
    """An artifact written by a format this code does not know."""


def check_version(found: object, known: int, kind: str, where: str) -> int:
    """Return `found` as int when it equals `known`; otherwise refuse naming the artifact.

    `kind` names the artifact type (e.g. 'views table'); `where` is its path.
    """
    try:
        value = int(str(found))
    except (TypeError, ValueError) as err:
        raise UnknownSchemaVersion(
            f"{where}: {kind} has no readable format version (found {found!r}); "
            f"this m3gd reads version {known}"
        ) from err
    if value != known:
        raise UnknownSchemaVersion(
            f"{where}: {kind} format version {value} is not supported by this m3gd "
            f"(reads version {known}); rebuild it or use a matching m3gd"
        )
    return value
