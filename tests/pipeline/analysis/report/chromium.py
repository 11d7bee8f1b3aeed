"""A headless Chromium driven over the Chrome DevTools protocol (tests only).

Debian's `chromium` is started by the test with `--remote-debugging-pipe`: protocol messages
travel as NUL-terminated JSON over two pipes (the child's fds 3 and 4), so no port is opened
and nothing beyond the standard library is needed (no websocket client, no Playwright with its
own Node driver and browser downloads). The profile is a new empty temporary folder.
"""

from __future__ import annotations

import fcntl
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--remote-debugging-pipe")


_EXEC_ON_3_4 = ("import os, sys; r, w = int(sys.argv[1]), int(sys.argv[2]); os.dup2(r, 3); "
                "os.dup2(w, 4); os.execv(sys.argv[3], sys.argv[3:])")
"""Child side: put the command pipe on fd 3 and the reply pipe on fd 4, then become chromium
(both ends are >= 10, so neither dup2 clobbers the other)."""


def chromium_binary() -> str | None:
    """Path of Debian's chromium, or None when it is not installed."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Browser:
    """One headless Chromium process; `page()` opens a tab session, `close()` ends it all."""

    def __init__(self, binary: str, timeout_s: float = 60.0) -> None:
        self.profile = Path(tempfile.mkdtemp(prefix="m3gd-chromium-"))
        cmd_r, self._cmd_w = _high_pipe()
        self._res_r, res_w = _high_pipe()
        args = [*FLAGS, f"--user-data-dir={self.profile}", "about:blank"]
        self.log = self.profile.with_suffix(".log")
        with open(self.log, "wb") as log:  # a tiny exec wrapper maps the pipes onto fds 3, 4
            self.proc = subprocess.Popen(
                [sys.executable, "-c", _EXEC_ON_3_4, str(cmd_r), str(res_w), binary, *args],
                pass_fds=(cmd_r, res_w), stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        os.close(cmd_r)
        os.close(res_w)
        self.timeout_s = timeout_s
        self._buf = b""
        self._id = 0
        self.events: list[dict[str, Any]] = []

    def send(self, method: str, params: dict[str, Any] | None = None,
             session: str | None = None) -> dict[str, Any]:
        """Send one command and wait for its answer (events seen meanwhile are kept)."""
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session is not None:
            msg["sessionId"] = session
        os.write(self._cmd_w, json.dumps(msg).encode() + b"\0")
        end = time.monotonic() + self.timeout_s
        while True:
            reply = self._next(end)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                result: dict[str, Any] = reply["result"]
                return result
            self.events.append(reply)

    def wait_event(self, method: str, session: str) -> dict[str, Any]:
        """Wait for the next event `method` of a session (or one already received)."""
        end = time.monotonic() + self.timeout_s
        while True:
            for i, ev in enumerate(self.events):
                if ev.get("method") == method and ev.get("sessionId") == session:
                    return self.events.pop(i)
            self.events.append(self._next(end))

    def _next(self, end: float) -> dict[str, Any]:
        """The next protocol message; TimeoutError past `end`."""
        while b"\0" not in self._buf:
            left = end - time.monotonic()
            poller = select.poll()  # poll, not select: the fd may be >= FD_SETSIZE (1024)
            poller.register(self._res_r, select.POLLIN)
            if left <= 0 or not poller.poll(left * 1000):
                raise TimeoutError("chromium did not answer in time")
            chunk = os.read(self._res_r, 1 << 20)
            if not chunk:
                raise RuntimeError(f"chromium exited (code {self.proc.wait()}): "
                                   f"{self.log.read_text(errors='replace')[-2000:]}")
            self._buf += chunk
        raw, _, self._buf = self._buf.partition(b"\0")
        message: dict[str, Any] = json.loads(raw)
        return message

    def page(self, url: str, width: int | None = None, height: int = 900) -> str:
        """Open `url` in a new tab with console, log and network events on; wait for its load
        event; return the session id. `width`: the viewport's CSS pixels (the browser's
        default window otherwise)."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = str(self.send("Target.attachToTarget", {"targetId": target,
                                                          "flatten": True})["sessionId"])
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.send(f"{domain}.enable", session=session)
        if width is not None:
            self.send("Emulation.setDeviceMetricsOverride", {
                "width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
                session=session)
        self.send("Page.navigate", {"url": url}, session=session)
        self.wait_event("Page.loadEventFired", session)
        return session

    def evaluate(self, session: str, expression: str) -> Any:
        """The JSON value of a JavaScript expression evaluated in the page (promises awaited)."""
        out = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                             "awaitPromise": True}, session=session)
        if "exceptionDetails" in out:
            raise RuntimeError(f"page script failed: {out['exceptionDetails']}")
        return out["result"].get("value")

    def navigate(self, session: str, url: str) -> None:
        """Load `url` in an open tab and wait for its load event."""
        self.send("Page.navigate", {"url": url}, session=session)
        self.wait_event("Page.loadEventFired", session)

    def close(self) -> None:
        """Close the browser and remove its profile."""
        try:
            self.send("Browser.close")
            self.proc.wait(timeout=20)
        except (RuntimeError, TimeoutError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        finally:
            os.close(self._cmd_w)
            os.close(self._res_r)
            shutil.rmtree(self.profile, ignore_errors=True)
            self.log.unlink(missing_ok=True)


def _high_pipe() -> tuple[int, int]:
    """A pipe whose two ends are fds >= 10, so mapping them onto 3 and 4 cannot clobber one."""
    r, w = os.pipe()
    hi = (fcntl.fcntl(r, fcntl.F_DUPFD_CLOEXEC, 10), fcntl.fcntl(w, fcntl.F_DUPFD_CLOEXEC, 10))
    os.close(r)
    os.close(w)
    return hi
