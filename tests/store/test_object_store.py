"""S3 locations: URL parsing, reachability errors as one line naming the URL."""

from __future__ import annotations

from pathlib import Path

import pytest

from store.object_store import (
    StorageError,
    StoreURL,
    check_location,
    filesystem,
    is_url,
    parse_url,
    read_bytes,
)


def test_parse_url_and_squeezed_path() -> None:
    assert parse_url("s3://bkt/a/b/") == StoreURL("bkt", "a/b")
    assert parse_url(Path("s3://bkt/a/b")) == StoreURL("bkt", "a/b")  # Path squeezes //
    assert parse_url("s3://bkt") == StoreURL("bkt", "")
    assert str(StoreURL("bkt", "a")) == "s3://bkt/a"
    assert StoreURL("bkt", "a").key("x/y") == "bkt/a/x/y"
    assert StoreURL("bkt", "").key("x") == "bkt/x"
    assert not is_url("out/cache") and not is_url(Path("/data/s3"))
    with pytest.raises(ValueError, match="no bucket"):
        parse_url("s3:///prefix")


def test_missing_bucket_and_object(s3: str) -> None:
    fs = filesystem()
    url = parse_url(s3)
    check_location(fs, url)  # the fixture's bucket exists
    assert read_bytes(fs, url, "nothing/here") is None
    missing = StoreURL("no-such-bucket-m3gd", "x")
    with pytest.raises(StorageError, match=r"s3://no-such-bucket-m3gd/x .*no such bucket"):
        check_location(fs, missing)


def test_wrong_endpoint_is_one_line(s3: str, monkeypatch: pytest.MonkeyPatch) -> None:
    from bench.support.local_s3 import free_port

    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{free_port()}")
    with pytest.raises(StorageError) as err:
        check_location(filesystem(), parse_url(s3))
    text = str(err.value)
    assert "\n" not in text and s3 in text and "cannot connect" in text
