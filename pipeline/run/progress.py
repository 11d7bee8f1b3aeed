"""Progress that reads well anywhere: rich bars on a terminal, plain log lines elsewhere.

`make_progress` returns a rich `Progress` when its console writes to a terminal and a
`LineProgress` otherwise (a log file, a pipe, CI). `LineProgress` has the part of rich's API the
commands use (`add_task`, `advance`, `update`, `start`, `stop`, context manager) and prints one
plain line per task at start, at every tenth of the total (at least MIN_GAP_S after the last
line) or after `every_s` seconds of silence, and at the end, so `m3gd eval > eval.out 2>
eval.err` shows where a long command is.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rich.console import Console
from rich.progress import Progress, ProgressColumn

EVERY_S = 10.0
"""Longest silence (seconds) of a running task in line mode."""
STEPS = 10
"""Line mode also prints at every 1/STEPS of a task's total ..."""
MIN_GAP_S = 2.0
"""... when at least this many seconds passed since the task's last line (a fast task prints
its first and last line only)."""


@dataclass
class _Task:
    """One task's counts and when its last line was printed."""

    description: str
    total: float | None
    completed: float
    fields: dict[str, Any]
    started: float
    last_line: float
    last_step: int = -1
    printed: float = -1.0
    finished: bool = False


@dataclass
class LineProgress:
    """rich-Progress-like progress printed as plain lines on `console` (see module doc)."""

    console: Console
    disable: bool = False
    every_s: float = EVERY_S
    clock: Callable[[], float] = time.monotonic
    tasks: dict[int, _Task] = field(default_factory=dict)

    def __enter__(self) -> LineProgress:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Nothing to start (lines are printed as the counts move)."""

    def stop(self) -> None:
        """Print the last count of every task whose count moved since its last line."""
        for task in self.tasks.values():
            if not task.finished and task.completed != task.printed:
                self._line(task)
            task.finished = True

    def add_task(self, description: str, total: float | None = None, completed: float = 0,
                 **fields: Any) -> int:
        """A new task; its first line is printed at once."""
        now = self.clock()
        task_id = len(self.tasks)
        task = _Task(description, total, completed, dict(fields), now, now)
        self.tasks[task_id] = task
        self._line(task)
        task.last_step = self._step(task)
        return task_id

    def advance(self, task_id: int, advance: float = 1) -> None:
        """Add `advance` to a task's count."""
        self.update(task_id, advance=advance)

    def update(self, task_id: int, *, total: float | None = None,
               completed: float | None = None, advance: float | None = None,
               description: str | None = None, **fields: Any) -> None:
        """Change a task's counts or fields; print a line when one is due."""
        task = self.tasks[task_id]
        if total is not None:
            task.total = total
        if completed is not None:
            task.completed = completed
        if advance is not None:
            task.completed += advance
        if description is not None:
            task.description = description
        task.fields.update(fields)
        self._maybe_line(task)

    def _step(self, task: _Task) -> int:
        """Which tenth of the total the task has reached (-1 without a total)."""
        if not task.total:
            return -1
        return int(STEPS * min(task.completed, task.total) / task.total)

    def _maybe_line(self, task: _Task) -> None:
        """Print a line at a new tenth (MIN_GAP_S after the last line), after every_s seconds
        of silence, or at the end."""
        if task.finished:
            return
        now = self.clock()
        step = self._step(task)
        done = task.total is not None and task.completed >= task.total
        quiet = now - task.last_line
        if done or (step > task.last_step and quiet >= MIN_GAP_S) or quiet >= self.every_s:
            self._line(task)
            task.last_step = step
            task.finished = done

    def _line(self, task: _Task) -> None:
        """One plain line: `name: done/total (pct %), elapsed s[, field value ...]`."""
        now = self.clock()
        task.last_line, task.printed = now, task.completed
        if self.disable:
            return
        count = f"{task.completed:g}"
        if task.total:
            count += f"/{task.total:g} ({100 * task.completed / task.total:.0f} %)"
        extra = "".join(f", {k} {v}" for k, v in task.fields.items() if v not in ("", None))
        self.console.print(f"{task.description}: {count}, {now - task.started:.0f} s{extra}",
                           highlight=False, markup=False, soft_wrap=True)


def make_progress(*columns: str | ProgressColumn, console: Console, transient: bool = False,
                  disable: bool = False) -> Progress | LineProgress:
    """A rich Progress with `columns` on a terminal; a LineProgress elsewhere."""
    if console.is_terminal:
        return Progress(*columns, console=console, transient=transient, disable=disable)
    return LineProgress(console, disable=disable)
