"""Progress as plain lines when the console is not a terminal (pipeline.run.progress)."""

from __future__ import annotations

import io

from rich.console import Console
from rich.progress import Progress

from pipeline.run.progress import EVERY_S, MIN_GAP_S, LineProgress, make_progress


class Clock:
    """A clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _lines(buf: io.StringIO) -> list[str]:
    return [line for line in buf.getvalue().splitlines() if line]


def _line_progress() -> tuple[LineProgress, io.StringIO, Clock]:
    buf, clock = io.StringIO(), Clock()
    return LineProgress(Console(file=buf, width=200), clock=clock), buf, clock


def test_not_a_terminal_gives_lines_a_terminal_gives_bars() -> None:
    plain = make_progress(console=Console(file=io.StringIO()))
    assert isinstance(plain, LineProgress)
    tty = make_progress(console=Console(file=io.StringIO(), force_terminal=True))
    assert isinstance(tty, Progress)


def test_start_tenths_and_end_are_printed_over_a_long_task() -> None:
    bar, buf, clock = _line_progress()
    with bar:
        task = bar.add_task("score clips", total=100)
        for _ in range(100):
            clock.now += 1.0  # 100 s in all: each tenth comes 10 s after the last line
            bar.advance(task)
    lines = _lines(buf)
    assert lines[0] == "score clips: 0/100 (0 %), 0 s"
    assert lines[-1] == "score clips: 100/100 (100 %), 100 s"
    assert len(lines) == 11  # start + ten tenths (the last is the end; stop adds nothing)


def test_a_fast_task_prints_its_first_and_last_line_only() -> None:
    bar, buf, clock = _line_progress()
    with bar:
        task = bar.add_task("align views", total=41)
        for _ in range(41):
            clock.now += (MIN_GAP_S / 2) / 41
            bar.advance(task)
    assert [line.split(":")[1].split(",")[0] for line in _lines(buf)] == [" 0/41 (0 %)",
                                                                          " 41/41 (100 %)"]


def test_silence_is_broken_every_every_s_even_inside_one_tenth() -> None:
    bar, buf, clock = _line_progress()
    task = bar.add_task("train", total=1000, loss="-")
    clock.now = EVERY_S - 0.01
    bar.update(task, completed=1, loss="0.5")
    assert len(_lines(buf)) == 1  # not yet: no new tenth, not every_s of silence
    clock.now = EVERY_S
    bar.update(task, completed=2, loss="0.4")
    assert _lines(buf)[-1] == "train: 2/1000 (0 %), 10 s, loss 0.4"


def test_stop_prints_an_unfinished_count_once_and_nothing_when_unchanged() -> None:
    bar, buf, clock = _line_progress()
    with bar:
        a = bar.add_task("a", total=10)
        bar.add_task("b", total=10)
        clock.now = 1.0
        bar.advance(a, 3)  # below MIN_GAP_S: no line yet
    lines = _lines(buf)
    assert lines == ["a: 0/10 (0 %), 0 s", "b: 0/10 (0 %), 0 s", "a: 3/10 (30 %), 1 s"]


def test_a_task_without_total_prints_its_count() -> None:
    bar, buf, clock = _line_progress()
    task = bar.add_task("rows")
    clock.now = EVERY_S
    bar.advance(task, 7)
    assert _lines(buf)[-1] == "rows: 7, 10 s"


def test_disabled_prints_nothing() -> None:
    buf = io.StringIO()
    with LineProgress(Console(file=buf), disable=True) as bar:
        bar.advance(bar.add_task("x", total=2), 2)
    assert buf.getvalue() == ""
