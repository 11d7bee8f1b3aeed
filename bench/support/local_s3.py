"""A real S3 API server on 127.0.0.1 for tests and benchmarks: moto's server mode in a child
process (dev dependency `moto[server]`), with its request log for honest request counts.

The server runs in its own process so its request handling does not share the client's
interpreter lock; every request it serves is one line of its log ("GET /bucket/key ..."),
which `requests()` counts by method (what the clients really sent, whatever library sent it).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from schemas.errors import DataError

_LINE = re.compile(r'"(?:\x1b\[[0-9;]*m)*(GET|PUT|HEAD|POST|DELETE) (\S+) HTTP')
"""A request line of werkzeug's log (colored by status: ANSI codes may precede the method)."""
START_TIMEOUT_S = 60.0


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


class LocalS3:
    """A moto S3 server child process; `env` holds the client settings (test credentials)."""

    def __init__(self, log: Path, enforce_auth: bool = False) -> None:
        self.port = free_port()
        self.endpoint = f"http://127.0.0.1:{self.port}"
        self.log = log
        env = dict(os.environ)
        if enforce_auth:  # every request must be signed with a key moto's IAM knows
            env["INITIAL_NO_AUTH_ACTION_COUNT"] = "0"
        self._out = log.open("wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(self.port)],
            stdout=self._out, stderr=subprocess.STDOUT, env=env)
        self._wait()

    @property
    def env(self) -> dict[str, str]:
        """Environment variables pointing a client at this server (dummy credentials)."""
        return {"AWS_ENDPOINT_URL": self.endpoint, "AWS_REGION": "us-east-1",
                "AWS_ACCESS_KEY_ID": "m3gd-test-key", "AWS_SECRET_ACCESS_KEY": "m3gd-secret"}

    def _wait(self) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise DataError(f"moto server exited: {self.log.read_text()[-300:]}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                return
            except OSError:
                time.sleep(0.1)
        self.stop()
        raise DataError(f"moto server on port {self.port} did not start")

    def requests(self) -> Counter[str]:
        """Requests served so far, by HTTP method (from the server's log)."""
        self._out.flush()
        return Counter(m.group(1) for m in _LINE.finditer(self.log.read_text(errors="replace")))

    def create_bucket(self, name: str) -> None:
        """Create bucket `name` (one PUT)."""
        import pyarrow.fs as pafs

        pafs.S3FileSystem(endpoint_override=f"127.0.0.1:{self.port}", scheme="http",
                          access_key="m3gd-test-key", secret_key="m3gd-secret",
                          region="us-east-1", allow_bucket_creation=True).create_dir(name)

    def stop(self) -> None:
        """Terminate the server process and close its log."""
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._out.close()


@contextmanager
def local_s3(log: Path, enforce_auth: bool = False) -> Iterator[LocalS3]:
    """A LocalS3 server for the duration of the block."""
    server = LocalS3(log, enforce_auth)
    try:
        yield server
    finally:
        server.stop()


@contextmanager
def environment(values: dict[str, str]) -> Iterator[None]:
    """os.environ with `values` set for the block, restored afterwards."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
