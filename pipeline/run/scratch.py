"""Worker-local scratch: where an item on object storage stages its inputs and outputs.

`$M3GD_SCRATCH` (default the temp dir) holds the folders; `$M3GD_SCRATCH_BYTES` (default 256 GiB)
bounds what one item stages at once.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

DEFAULT_LIMIT_BYTES = 256 * 2**30


def scratch_root() -> Path:
    """Folder under which missions are staged: $M3GD_SCRATCH or the temp dir."""
    return Path(os.environ.get("M3GD_SCRATCH") or tempfile.gettempdir())


def limit_bytes() -> int:
    """Largest mission staged at once: $M3GD_SCRATCH_BYTES or 256 GiB."""
    return int(os.environ.get("M3GD_SCRATCH_BYTES") or DEFAULT_LIMIT_BYTES)
