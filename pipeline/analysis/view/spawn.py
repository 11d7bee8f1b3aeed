"""`m3gd view --spawn`: open a written `.rrd` in the Rerun viewer where a display exists."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

RERUN_PIN = "rerun-sdk==0.41.0"
"""The SDK version m3gd writes with (pyproject.toml); a viewer of the same version opens it."""


def has_display(env: Mapping[str, str] | None = None, platform: str = sys.platform) -> bool:
    """Whether a native viewer window can open: macOS and Windows always; elsewhere only with
    $DISPLAY (X11) or $WAYLAND_DISPLAY set."""
    env = os.environ if env is None else env
    if platform in ("darwin", "win32"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def how_to_open(path: Path) -> str:
    """One line telling how to open `path` on a machine with a display."""
    return (f"open it where a display exists with `rerun {path}` ({RERUN_PIN}; the viewer is "
            "the `rerun` command of that package)")


def open_viewer(path: Path, env: Mapping[str, str] | None = None,
                popen: Callable[..., Any] = subprocess.Popen) -> str:
    """Start the Rerun viewer on `path` in the background when a display exists; return what
    was done. Without a display nothing is started and the message says how to open the file."""
    if not has_display(env):
        return f"no display here ($DISPLAY and $WAYLAND_DISPLAY unset); {how_to_open(path)}"
    popen([sys.executable, "-m", "rerun", str(path)], start_new_session=True,
          stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return f"opened {path} in the Rerun viewer"
