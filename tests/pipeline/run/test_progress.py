"""Progress as plain lines when the console is not a terminal (pipeline.run.progress)."""

from __future__ import annotations

import io
import time

import pytest
from rich.console import Console
from rich.progress import Progress

from pipeline.run.progress import (
    EVERY_S,
    MIN_GAP_S,
    LineProgress,
    duration,
    make_progress,
    rate_and_eta,
)


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
    return LineProgress(Console(file=buf, width=200), clock=clock, ticker=False), buf, clock


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
    assert _lines(buf)[-1] == "train: 2/1000 (0 %), 10 s, 0.2/s, ETA 83 min, loss 0.4"


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
    assert _lines(buf)[-1] == "rows: 7, 10 s, 0.7/s"


def test_disabled_prints_nothing() -> None:
    buf = io.StringIO()
    with LineProgress(Console(file=buf), disable=True) as bar:
        bar.advance(bar.add_task("x", total=2), 2)
    assert buf.getvalue() == ""


def test_a_long_item_is_reported_every_every_s_without_any_advance() -> None:
    bar, buf, clock = _line_progress()
    task = bar.add_task("packets", total=2)
    for second in range(1, 35):
        clock.now = float(second)
        bar.tick()  # what the ticker thread does every TICK_S
    assert _lines(buf) == ["packets: 0/2 (0 %), 0 s", "packets: 0/2 (0 %), 10 s, none done yet",
                           "packets: 0/2 (0 %), 20 s, none done yet",
                           "packets: 0/2 (0 %), 30 s, none done yet"]
    clock.now = 40.0
    bar.advance(task)
    assert _lines(buf)[-1] == "packets: 1/2 (50 %), 40 s, 0.025/s, ETA 40 s"


def test_the_ticker_thread_prints_while_nothing_advances() -> None:
    buf = io.StringIO()
    with LineProgress(Console(file=buf, width=200), every_s=0.05) as bar:
        bar.add_task("encode", total=3)
        time.sleep(0.6)
    lines = _lines(buf)
    assert len(lines) >= 3, lines  # the start line and at least two ticks
    assert all(line.startswith("encode: 0/3 (0 %)") for line in lines)


def test_a_failed_item_is_counted_apart_and_the_task_never_reads_100() -> None:
    bar, buf, clock = _line_progress()
    with bar:
        task = bar.add_task("ingest", total=1)
        clock.now = 3.0
        bar.update(task, failed=1)
    assert _lines(buf) == ["ingest: 0/1 (0 %), 0 s", "ingest: 0/1 (0 %), 1 failed, 3 s"]


def test_percent_reads_100_only_when_every_item_is_done() -> None:
    bar, buf, clock = _line_progress()
    with bar:
        task = bar.add_task("views", total=1000)
        clock.now = 5.0
        bar.update(task, completed=999)
    assert _lines(buf)[-2:] == ["views: 999/1000 (99 %), 5 s, 200/s, ETA 0 s",
                                "views: 999/1000 (99 %), 5 s"]  # stopped one short


@pytest.mark.parametrize(("seconds", "text"), [(0, "0 s"), (89.4, "89 s"), (90, "2 min"),
                                               (5399, "90 min"), (5400, "1.5 h")])
def test_duration_boundaries(seconds: float, text: str) -> None:
    assert duration(seconds) == text


def test_rate_and_eta_cases() -> None:
    assert rate_and_eta(0, 10, 0.0) == ""  # the first line
    assert rate_and_eta(0, 10, 5.0) == ", none done yet"
    assert rate_and_eta(5, 10, 5.0) == ", 1/s, ETA 5 s"
    assert rate_and_eta(5, None, 5.0) == ", 1/s"
    assert rate_and_eta(10, 10, 5.0) == ""  # done: no pace


def test_stop_ends_a_task_without_total_on_a_final_line() -> None:
    bar, buf, clock = _line_progress()
    with bar:
        task = bar.add_task("accuracy views")
        clock.now = EVERY_S
        bar.advance(task, 5)  # an intermediate line, with its rate
    assert _lines(buf) == ["accuracy views: 0, 0 s", "accuracy views: 5, 10 s, 0.5/s",
                           "accuracy views: 5, 10 s"]


def test_a_terminal_bar_prints_its_description_as_it_is() -> None:
    """A recording or a path holding `[` is data: on a terminal the default bar neither
    parses it as markup (was: a MarkupError for `[/x]`, a vanished `[draft]`)."""
    from pipeline.run.progress import make_progress

    buffer = io.StringIO()
    console = Console(file=buffer, force_terminal=True, width=120)
    with make_progress(console=console) as bar:
        task = bar.add_task("/data/[draft]/b[/x] views", total=2)
        bar.advance(task, 2)
    assert isinstance(bar, Progress) and "/data/[draft]/b[/x] views" in buffer.getvalue()
