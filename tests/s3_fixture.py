"""A real S3 API server for the tests: moto's server mode in a child process on 127.0.0.1.

`s3_server` (session): the server, started once on a free port. `s3` (per test): a fresh
bucket and the client environment (endpoint, region, test credentials) set in os.environ,
yielding the test's `s3://bucket/prefix` base URL.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.storage_bench import upload_tree
from bench.support.local_s3 import LocalS3, environment, local_s3

_BUCKETS = itertools.count()


@pytest.fixture(scope="session")
def s3_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalS3]:
    """One moto S3 server for the session (its log under the session's temp dir)."""
    pytest.importorskip("moto.server", reason="moto[server] (dev dependency) not installed")
    with local_s3(tmp_path_factory.mktemp("moto") / "server.log") as server:
        yield server


@pytest.fixture
def s3(s3_server: LocalS3, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A fresh bucket on the session's server, client environment set; yields its URL."""
    bucket = f"m3gd-test-{next(_BUCKETS)}"
    for key, value in s3_server.env.items():
        monkeypatch.setenv(key, value)
    s3_server.create_bucket(bucket)
    yield f"s3://{bucket}/out"


def upload(local: Path, url: str) -> None:
    """Copy the directory tree `local` to the location `url` (test set-up: the write side
    of object storage is not built yet)."""
    upload_tree(local, url)


__all__ = ["environment", "upload"]
