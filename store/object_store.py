"""Object-storage locations (`s3://bucket/prefix`): parsing, the filesystem, one-line errors.

An output or recording location is either a local path or an S3 URL (AWS S3 or any
S3-compatible store). The connection comes from the usual environment, never from m3gd's
config or outputs:
- endpoint: `AWS_ENDPOINT_URL_S3` or `AWS_ENDPOINT_URL` (unset: AWS itself);
- region: `AWS_REGION` or `AWS_DEFAULT_REGION` (default us-east-1);
- credentials: the AWS SDK's default chain inside Arrow (`AWS_ACCESS_KEY_ID` /
  `AWS_SECRET_ACCESS_KEY` / `AWS_SESSION_TOKEN`, `~/.aws`, instance roles). m3gd never reads
  or handles the secret itself, so no message, log or manifest can contain it.

The filesystem is pyarrow's `S3FileSystem` (the AWS C++ SDK): one dependency already
installed for Parquet, picklable (DataLoader workers, Dask), readable by DuckDB through
Arrow datasets, and it does ranged reads (`read_at`) as well as whole-object GETs.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow.fs as pafs

from schemas.errors import DataError

SCHEME = "s3://"
CONNECT_TIMEOUT_S = 5.0
REQUEST_TIMEOUT_S = 60.0


class StorageError(DataError):
    """Permanent: the object store is unreachable, the bucket missing or access refused.
    The message is one line naming the URL (and the endpoint), never the credentials."""


@dataclass(frozen=True)
class StoreURL:
    """`s3://bucket/prefix`: bucket name and key prefix (no leading or trailing slash)."""

    bucket: str
    prefix: str

    def __str__(self) -> str:
        return f"{SCHEME}{self.bucket}/{self.prefix}".rstrip("/")

    def key(self, rel: str) -> str:
        """Arrow path `bucket/prefix/rel` of the object `rel` below this location."""
        return "/".join(p for p in (self.bucket, self.prefix, rel.strip("/")) if p)

    def url(self, rel: str) -> str:
        """Full URL of the object `rel` below this location (for messages)."""
        return f"{SCHEME}{self.key(rel)}"

    def child(self, rel: str) -> StoreURL:
        """The location `rel` below this one."""
        return StoreURL(self.bucket, "/".join(p for p in (self.prefix, rel.strip("/")) if p))


def is_url(location: str | Path) -> bool:
    """True for an `s3://` URL, also after `Path` squeezed its double slash (`s3:/b/p`)."""
    text = str(location)
    return text.startswith(SCHEME) or text.startswith("s3:/")


def display(location: str | Path) -> str:
    """A location as the user wrote it: `s3://bucket/prefix` (not `Path`'s `s3:/…`)."""
    return str(parse_url(location)) if is_url(location) else str(location)


def parse_url(location: str | Path) -> StoreURL:
    """`s3://bucket/prefix` (or a `Path` of it, `s3:/bucket/prefix`) as a StoreURL."""
    text = str(location)
    if not is_url(text):
        raise DataError(f"{text}: not an s3:// URL")
    rest = text[len(SCHEME):] if text.startswith(SCHEME) else text[len("s3:/"):]
    bucket, _, prefix = rest.partition("/")
    if not bucket:
        raise DataError(f"{text}: no bucket in the URL (expected s3://bucket/prefix)")
    return StoreURL(bucket, prefix.strip("/"))


def endpoint() -> str | None:
    """The S3 endpoint URL from the environment, or None for AWS itself."""
    return os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL") or None


def region() -> str:
    """The region from the environment (default us-east-1)."""
    return os.environ.get("AWS_REGION") or os.environ.get("AWS_DEFAULT_REGION") or "us-east-1"


def filesystem() -> pafs.S3FileSystem:
    """An Arrow S3 filesystem configured from the environment (see the module docstring);
    short connect timeout and few retries so a wrong endpoint fails in seconds."""
    kw: dict[str, Any] = {
        "region": region(),
        "connect_timeout": CONNECT_TIMEOUT_S, "request_timeout": REQUEST_TIMEOUT_S,
        "retry_strategy": pafs.AwsStandardS3RetryStrategy(max_attempts=3),
        # an object smaller than one part goes up in a single PUT, not a multipart upload
        # (create, part, complete): 1 request instead of 3 (measured on the moto server)
        "allow_delayed_open": True,
    }
    url = endpoint()
    if url:
        scheme, _, host = url.partition("://")
        kw |= {"endpoint_override": host or scheme, "scheme": scheme if host else "https"}
    return pafs.S3FileSystem(**kw)


def where(url: StoreURL | str) -> str:
    """`url` and the endpoint it is reached at, for error messages (no credentials)."""
    return f"{url} (endpoint {endpoint() or 'AWS default'})"


def reason(err: BaseException) -> str:
    """The first line of an Arrow / AWS SDK error, classified: unreachable endpoint,
    refused credentials, or as reported."""
    text = " ".join(str(err).split())
    low = text.lower()
    if any(m in low for m in ("curlcode", "couldn't connect", "could not connect",
                              "connection refused")):
        return "cannot connect to the endpoint"
    for marker in ("access_denied", "accessdenied", "invalidaccesskeyid", "signature",
                   "forbidden", "403"):
        if marker in low:
            return "access denied (check the credentials)"
    return text[:200]


def check_location(fs: pafs.FileSystem, url: StoreURL) -> None:
    """Raise StorageError (one line naming the URL) unless the bucket is reachable."""
    try:
        info = fs.get_file_info(url.bucket)
    except OSError as err:
        raise StorageError(f"{where(url)}: {reason(err)}") from err
    if info.type == pafs.FileType.NotFound:
        raise StorageError(f"{where(url)}: no such bucket {url.bucket!r}")


def read_bytes(fs: pafs.FileSystem, url: StoreURL, rel: str) -> bytes | None:
    """The whole object `rel` below `url` (one GET), or None when it does not exist."""
    try:
        with fs.open_input_stream(url.key(rel)) as stream:
            data: bytes = stream.read()
    except FileNotFoundError:
        return None
    except OSError as err:
        raise StorageError(f"{where(url.url(rel))}: {reason(err)}") from err
    return data
