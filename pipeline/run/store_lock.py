"""The output lock of an output on object storage: one object created by a conditional PUT.

`acquire` PUTs `<prefix>/.m3gd.lock` (the holder's host, pid and start time) with
`If-None-Match: *`: the store creates it only if no object has that key, atomically, so of
two runs starting together exactly one gets it (AWS S3 has honoured the header since
August 2024; the moto server the tests start does, tested; a store that ignores it would
let a second run overwrite the lock, which `acquire` then detects by reading the lock back
and refusing when it names another run, a check that narrows but cannot close the race).
`release` deletes the object only if it is still the one this run wrote (`If-Match` on its
ETag).

Unlike `flock`, nothing releases the object when its holder dies. A lock naming this host
and a process that no longer exists is taken over (a killed run's lock, rerun on the same
machine); a lock naming another host is refused with what to do, `m3gd unlock s3://…` or
`m3gd run --break-lock`, since m3gd cannot tell from here whether that run is still alive.
Connection settings and credentials come from the environment (`store.object_store`).
"""

from __future__ import annotations

import json
import os
import socket
import time
from dataclasses import asdict
from pathlib import Path
from types import TracebackType
from typing import Any

from pipeline.run.lock import LOCK_NAME, Holder, LockHeld
from pipeline.run.store_sync import client
from store.object_store import StorageError, parse_url, reason, where

ATTEMPTS = 5


def _code(err: Exception) -> str:
    """The S3 error code of a botocore ClientError ('' for other errors)."""
    response = getattr(err, "response", None)
    return str(response.get("Error", {}).get("Code", "")) if isinstance(response, dict) else ""


def _alive_here(holder: Holder) -> bool:
    """Whether `holder` names a process of this host that still exists."""
    if holder.host != socket.gethostname():
        return False
    try:
        os.kill(holder.pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class StoreLock:
    """Context manager holding the lock object of one output on the store."""

    def __init__(self, location: Path | str, break_lock: bool = False) -> None:
        """`break_lock`: take over a lock naming another host (the user says it is gone)."""
        self.url = parse_url(location)
        self.key = "/".join(p for p in (self.url.prefix, LOCK_NAME) if p)
        self.where = where(self.url.url(LOCK_NAME))
        self.me = Holder(socket.gethostname(), os.getpid(), time.time())
        self.break_lock = break_lock
        self.took_over: Holder | None = None
        self._etag: str | None = None
        self._s3 = client()

    def _call(self, name: str, **kw: Any) -> Any:
        """One S3 call on the lock object; StorageError (one line) for the store's errors
        except the ones the caller handles (412, 404, 409), which are re-raised."""
        from botocore.exceptions import BotoCoreError, ClientError

        try:
            return getattr(self._s3, name)(Bucket=self.url.bucket, Key=self.key, **kw)
        except ClientError as err:
            if _code(err) in ("PreconditionFailed", "NoSuchKey", "404",
                              "ConditionalRequestConflict"):
                raise
            if _code(err) == "NoSuchBucket":
                raise StorageError(f"{self.where}: no such bucket {self.url.bucket!r}") from err
            raise StorageError(f"{self.where}: {reason(err)}") from err
        except BotoCoreError as err:
            raise StorageError(f"{self.where}: {reason(err)}") from err

    def read(self) -> tuple[Holder | None, str | None]:
        """(holder, ETag) of the lock object; (None, None) when there is none."""
        from botocore.exceptions import ClientError

        try:
            got = self._call("get_object")
        except ClientError:
            return None, None
        try:
            holder = Holder(**json.loads(got["Body"].read()))
        except (ValueError, TypeError):
            holder = None
        return holder, str(got["ETag"])

    def _create(self) -> bool:
        """PUT the lock object if none exists; True when this run created it."""
        from botocore.exceptions import ClientError

        try:
            put = self._call("put_object", Body=json.dumps(asdict(self.me)).encode(),
                             IfNoneMatch="*", ContentType="application/json")
        except ClientError:  # 412: it exists; 409: a concurrent conditional write won
            return False
        self._etag = str(put["ETag"])
        return True

    def _delete(self, etag: str) -> bool:
        """Delete the lock object if its ETag is still `etag`; True when deleted (or gone)."""
        from botocore.exceptions import ClientError

        try:
            self._call("delete_object", IfMatch=etag)
        except ClientError as err:
            return _code(err) in ("NoSuchKey", "404")
        return True

    def acquire(self) -> None:
        """Take the lock; LockHeld naming the holder when a live run (or another host) has it."""
        for _ in range(ATTEMPTS):
            if self._create():
                holder, _ = self.read()
                if holder == self.me:
                    return
                raise LockHeld(f"{self.url} is locked by another m3gd run "
                               f"({holder.describe() if holder else 'holder unreadable'}): "
                               "the store ignored the conditional write")
            holder, etag = self.read()
            if etag is None:
                continue  # released meanwhile: try again
            if holder is not None and _alive_here(holder):
                raise LockHeld(f"{self.url} is locked by another m3gd run ({holder.describe()})")
            if holder is not None and holder.host != self.me.host and not self.break_lock:
                raise LockHeld(
                    f"{self.url} is locked by an m3gd run on another host "
                    f"({holder.describe()}); m3gd cannot tell from here whether it is still "
                    f"running. If it is not, run `m3gd unlock {self.url}` "
                    "(or `m3gd run --break-lock`)")
            if self._delete(etag):  # a dead run of this host, or broken on purpose
                self.took_over = holder
        raise LockHeld(f"{self.url}: could not take the lock in {ATTEMPTS} attempts "
                       "(other runs keep taking it)")

    def release(self) -> None:
        """Delete the lock object if this run still holds it."""
        if self._etag is not None:
            self._delete(self._etag)
            self._etag = None

    def __enter__(self) -> StoreLock:
        self.acquire()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()


def unlock_store(location: Path | str) -> Holder | None:
    """Remove the lock object of an output on the store unless a live run of this host
    holds it; return the old holder (None when there was no lock)."""
    lock = StoreLock(location, break_lock=True)
    holder, etag = lock.read()
    if etag is None:
        return None
    if holder is not None and _alive_here(holder):
        raise LockHeld(f"{lock.url} is locked by a running m3gd run ({holder.describe()})")
    lock._delete(etag)
    return holder
