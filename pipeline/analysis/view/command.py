"""`m3gd view` as a plain function: write the `.rrd`, then open it or say how to."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from pipeline.analysis.view.spawn import how_to_open, open_viewer
from pipeline.analysis.view.writer import ViewOptions, write_view
from schemas.config import M3GDConfig


def default_path(cfg: M3GDConfig, recording: str | None) -> Path:
    """`<output_dir>/view/<recording>.rrd` (the run's first recording when None)."""
    from schemas.missions import recording_names

    names = recording_names(cfg)
    name = recording or (names[0] if names else "recording")
    return cfg.layout.view / f"{name}.rrd"


def run_view(cfg: M3GDConfig, opts: ViewOptions, out: Path | None = None,
             spawn: bool = False,
             on_views: Callable[[int, int], None] | None = None) -> list[str]:
    """Write the recording file of `opts` (to `out` or the default path); the lines to print:
    what was skipped, what the file holds, and how it was or can be opened."""
    path = out or default_path(cfg, opts.recording)
    result = write_view(cfg, path, opts, on_views)
    lines = list(result.messages)
    lines.append(f"wrote {path} ({result.bytes / 1e6:.1f} MB): {result.views} views of "
                 f"{result.recording} over {result.duration_s:.1f} s, {result.sweeps} sweeps, "
                 f"{result.events} reject events")
    lines.append(open_viewer(path) if spawn else how_to_open(path))
    return lines
