"""Rates and gaps of one topic from its message times (pure).

A gap is an interval between consecutive messages longer than `GAP_FACTOR` times the topic's
median interval (strictly longer: an interval of exactly GAP_FACTOR periods is not a gap).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from pipeline.inspect.model import Gap

GAP_FACTOR = 2.5
"""An interval longer than this many median intervals is a gap (a dropped or late message
gives 2; a lost second of a 10 Hz stream 11)."""
MAX_GAPS = 5
"""Gaps listed per topic (longest first); `n_gaps` counts all of them."""
NS = 1_000_000_000


@dataclass(frozen=True)
class Timing:
    """first/last time (ns), rate (Hz), median period (s), gaps (longest first), gap count."""

    first_ns: int | None
    last_ns: int | None
    rate_hz: float | None
    period_s: float | None
    gaps: tuple[Gap, ...]
    n_gaps: int


def timing(times_ns: npt.ArrayLike) -> Timing:
    """Timing of message times (N,) int64 ns, in any order (sorted here).

    One message: no rate or period; none: all None. Equal times (duplicates) give a zero
    interval; a median interval of zero (a burst) finds no gaps.
    """
    t = np.sort(np.asarray(times_ns, dtype=np.int64))
    if t.size == 0:
        return Timing(None, None, None, None, (), 0)
    first, last = int(t[0]), int(t[-1])
    if t.size == 1 or last == first:
        return Timing(first, last, None, None, (), 0)
    dt = np.diff(t)
    period = float(np.median(dt))
    rate = (t.size - 1) * NS / (last - first)
    if period <= 0:
        return Timing(first, last, rate, 0.0, (), 0)
    idx = np.flatnonzero(dt > GAP_FACTOR * period)
    order = idx[np.argsort(-dt[idx], kind="stable")][:MAX_GAPS]
    gaps = tuple(Gap(int(t[i]), float(dt[i]) / NS) for i in order)
    return Timing(first, last, rate, period / NS, gaps, int(idx.size))
