"""Progress that reads well anywhere: rich bars on a terminal, plain log lines elsewhere.

`make_progress` returns a rich `Progress` when its console writes to a terminal and a
`LineProgress` otherwise (a log file, a pipe, CI). `LineProgress` has the part of rich's API the
commands use (`add_task`, `advance`, `update`, `start`, `stop`, context manager) and prints one
plain line per task at start, at every tenth of the total (at least MIN_GAP_S after the last
line), after `every_s` seconds of silence (a background ticker prints it even while one long
item runs and nothing calls `advance`), and at the end, so `m3gd eval > eval.out 2> eval.err`
shows where a long command is. A line carries the items done, the rate and the time left
(`packets: 1/4 (25 %), 40 s, 0.025/s, ETA 2 min`). Items that failed are counted apart
(`update(task, failed=n)`): a task with a failed item never reads 100 %.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rich.console import Console
from rich.progress import Progress, ProgressColumn, TaskID, TextColumn

EVERY_S = 10.0
"""Longest silence (seconds) of a running task in line mode."""
STEPS = 10
"""Line mode also prints at every 1/STEPS of a task's total ..."""
TICK_S = 1.0
"""How often (wall seconds) the ticker thread looks for a task silent for `every_s`."""
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
    paced: bool = False
    """Whether the last line carried a rate (an intermediate line: stop prints a final one)."""

    @property
    def failed(self) -> int:
        """Items counted as failed (the `failed` field)."""
        return int(self.fields.get("failed") or 0)

    def done(self) -> bool:
        """Every item ended, done or failed."""
        return self.total is not None and self.completed + self.failed >= self.total


def duration(seconds: float) -> str:
    """`42 s`, `3 min`, `1.5 h`: a time left, rounded to what a reader needs."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def rate_and_eta(completed: float, total: float | None, elapsed: float) -> str:
    """`, 0.5/s, ETA 40 s` for a task under way; `, none done yet` before its first item."""
    if elapsed <= 0 or (total is not None and completed >= total):
        return ""
    if completed <= 0:
        return ", none done yet"
    rate = completed / elapsed
    text = f", {rate:.3g}/s"
    if total:
        text += f", ETA {duration((total - completed) / rate)}"
    return text


@dataclass
class LineProgress:
    """rich-Progress-like progress printed as plain lines on `console` (see module doc)."""

    console: Console
    disable: bool = False
    every_s: float = EVERY_S
    clock: Callable[[], float] = time.monotonic
    tasks: dict[int, _Task] = field(default_factory=dict)
    ticker: bool = True
    """Start a thread that calls `tick` every TICK_S (off in tests that drive the clock)."""
    _lock: threading.RLock = field(default_factory=threading.RLock, repr=False)
    _halt: threading.Event = field(default_factory=threading.Event, repr=False)
    _thread: threading.Thread | None = field(default=None, repr=False)

    def __enter__(self) -> LineProgress:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Start the ticker thread (lines between counts of a long item)."""
        if self.ticker and not self.disable and self._thread is None:
            self._halt.clear()
            self._thread = threading.Thread(target=self._tick_loop, name="progress-ticker",
                                            daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the ticker; print the last count (without rate) of every unfinished task whose
        count moved since its last line or whose last line was an intermediate one."""
        if self._thread is not None:
            self._halt.set()
            self._thread.join()
            self._thread = None
        with self._lock:
            for task in self.tasks.values():
                if not task.finished and (task.completed != task.printed or task.paced):
                    self._line(task, pace=False)
                task.finished = True

    def _tick_loop(self) -> None:
        while not self._halt.wait(min(TICK_S, self.every_s)):
            self.tick()

    def tick(self) -> None:
        """Print a line for every running task silent for `every_s` (the ticker calls it)."""
        with self._lock:
            now = self.clock()
            for task in self.tasks.values():
                if not task.finished and now - task.last_line >= self.every_s:
                    self._line(task)

    def add_task(self, description: str, total: float | None = None, completed: float = 0,
                 **fields: Any) -> TaskID:
        """A new task; its first line is printed at once."""
        with self._lock:
            now = self.clock()
            task_id = len(self.tasks)
            task = _Task(description, total, completed, dict(fields), now, now)
            self.tasks[task_id] = task
            self._line(task, pace=False)
            task.last_step = self._step(task)
            return TaskID(task_id)

    def advance(self, task_id: int, advance: float = 1) -> None:
        """Add `advance` to a task's count."""
        self.update(task_id, advance=advance)

    def update(self, task_id: int, *, total: float | None = None,
               completed: float | None = None, advance: float | None = None,
               description: str | None = None, **fields: Any) -> None:
        """Change a task's counts or fields (`failed=n`: items that failed); print a line when
        one is due."""
        with self._lock:
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
        done = task.done()
        quiet = now - task.last_line
        if done or (step > task.last_step and quiet >= MIN_GAP_S) or quiet >= self.every_s:
            self._line(task)
            task.last_step = step
            task.finished = done

    def _line(self, task: _Task, pace: bool = True) -> None:
        """One plain line: `name: done/total (pct %)[, n failed], elapsed s[, rate, ETA]
        [, field value ...]`; the percentage counts done items only."""
        now = self.clock()
        task.last_line, task.printed = now, task.completed
        if self.disable:
            return
        count = f"{task.completed:g}"
        if task.total:
            count += f"/{task.total:g} ({_percent(task.completed, task.total)} %)"
        if task.failed:
            count += f", {task.failed} failed"
        elapsed = now - task.started
        speed = rate_and_eta(task.completed, task.total, elapsed)
        speed = speed if pace and not task.done() else ""
        task.paced = bool(speed)
        extra = "".join(f", {k} {v}" for k, v in task.fields.items()
                        if k != "failed" and v not in ("", None))
        self.console.print(f"{task.description}: {count}, {elapsed:.0f} s{speed}{extra}",
                           highlight=False, markup=False, soft_wrap=True)


def _percent(completed: float, total: float) -> str:
    """Whole percent, 100 only when every item is done (99.6 % reads 99)."""
    pct = 100 * completed / total
    return "100" if completed >= total else f"{min(pct, 99):.0f}"


def plain_columns() -> tuple[ProgressColumn, ...]:
    """rich's default columns, the task's description printed as it is (a path or a
    recording name holding `[` is data, not markup)."""
    return (TextColumn("{task.description}", markup=False, style="progress.description"),
            *Progress.get_default_columns()[1:])


def make_progress(*columns: str | ProgressColumn, console: Console, transient: bool = False,
                  disable: bool = False) -> Progress | LineProgress:
    """A rich Progress with `columns` on a terminal (by default rich's, the description
    printed as it is: never parsed as markup); a LineProgress elsewhere."""
    if console.is_terminal:
        return Progress(*(columns or plain_columns()), console=console, transient=transient,
                        disable=disable)
    return LineProgress(console, disable=disable)
