"""A full disk or a read-only folder while `plot`, `accuracy`, `align` (and `--consistency`),
`report` and `view` write: one line naming the file and what to do, exit 1, no traceback."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pyarrow as pa
import pytest
from typer.testing import CliRunner

from cli.app import app

FULL = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "out/stats/x.parquet")
READ_ONLY = OSError(errno.EROFS, os.strerror(errno.EROFS), "out/stats/x.parquet")


def _raise(err: OSError) -> Any:
    def write(*args: object, **kwargs: object) -> Any:
        raise err
    return write


def _patch(monkeypatch: pytest.MonkeyPatch, command: str, err: OSError) -> list[str]:
    """Make `command` fail with `err` where it writes; its arguments."""
    import pipeline.analysis.accuracy as accuracy
    import pipeline.analysis.align as align
    import pipeline.analysis.align_consistency as consistency
    import pipeline.analysis.figures as figures
    import pipeline.analysis.report.build as report
    import pipeline.analysis.view.command as view

    if command == "plot":
        monkeypatch.setattr(figures, "make_plots", _raise(err))
        return ["plot"]
    if command == "accuracy":
        monkeypatch.setattr(accuracy, "run_accuracy", _raise(err))
        return ["accuracy"]
    if command == "align":
        monkeypatch.setattr(align, "count_views", lambda *a: 1)
        monkeypatch.setattr(align, "run_alignment", lambda *a: pa.table({"images": [3]}))
        monkeypatch.setattr(align, "write_alignment", _raise(err))
        return ["align"]
    if command == "consistency":
        monkeypatch.setattr(consistency, "run_consistency", lambda *a, **k: SimpleNamespace(
            table=pa.table({"camera": ["front"]}), skipped={}))
        monkeypatch.setattr(consistency, "write_consistency", _raise(err))
        return ["align", "--consistency"]
    if command == "report":
        monkeypatch.setattr(report, "run_report", _raise(err))
        return ["report", "--no-plots"]
    monkeypatch.setattr(view, "run_view", _raise(err))
    return ["view"]


@pytest.mark.parametrize("err", [FULL, READ_ONLY], ids=["full", "read-only"])
@pytest.mark.parametrize("command", ["plot", "accuracy", "align", "consistency", "report",
                                     "view"])
def test_a_failed_write_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                    command: str, err: OSError) -> None:
    (tmp_path / "out").mkdir()
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"output_dir: {tmp_path / 'out'}\n")
    args = _patch(monkeypatch, command, err)
    result = CliRunner().invoke(app, ["-c", str(cfg), *args])
    text = result.output.strip()
    assert result.exit_code == 1 and not isinstance(result.exception, OSError), text
    *progress, last = text.splitlines()
    assert "Traceback" not in text and all(" views: " in line for line in progress), text
    assert last.startswith(f"error: out/stats/x.parquet: {err.strerror}; the "), text
    assert "not written" in last and "run the same command again" in last
