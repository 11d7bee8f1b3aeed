"""Point-time conventions: the table's rule, encode/decode round trips, `auto` inference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.time_conventions import (
    CONVENTIONS,
    DRIVERS,
    HEADER_OFFSET_MAX,
    NS_PER_UNIT,
    SPAN_RATIO,
    SweepTimes,
    TimeConvention,
    TimeEvidence,
    by_name,
    from_ns,
    held,
    infer,
    to_ns,
)

EPOCH_NS = 1_700_000_000_123_456_789


def _sweeps(conv: TimeConvention, n: int = 8, period_ns: int = 100_000_000,
            points: int = 500, t0: int = EPOCH_NS, span: float = 0.97,
            seed: int = 0) -> list[SweepTimes]:  # fmt: skip
    """Sweeps as a driver of `conv` writes them: points over `span` of each period, the header
    at the first point (its last for `header`)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        start = t0 + i * period_ns
        t = np.sort(start + rng.integers(0, int(span * period_ns), points))
        t[0] = start
        head = int(t[-1]) if conv.reference == "header" else int(t[0])
        v = from_ns(t, head, conv).astype(np.float64)
        out.append(SweepTimes(head, v, float(v.min())))
    return out


def test_the_table_is_the_matrix_minus_what_a_dtype_cannot_hold() -> None:
    assert len(CONVENTIONS) == 32
    names = {c.name for c in CONVENTIONS}
    assert "float64_ns_absolute" in names and "uint32_us_first_point" in names
    assert "float32_ns_absolute" not in names  # 2.7e11 ns steps at an epoch stamp
    assert "uint32_ns_absolute" not in names  # overflows
    assert "uint32_ns_header" not in names  # negative offsets
    assert "int64_ms_first_point" not in names  # 1 ms steps
    assert held("float32", "ns", "absolute") and held("uint64", "s", "absolute")
    for conv in DRIVERS.values():
        assert held(conv.dtype, conv.unit, conv.reference) is None, conv
    with pytest.raises(KeyError):
        by_name("float32_s_absolute")


@pytest.mark.parametrize("conv", CONVENTIONS, ids=lambda c: c.name)
def test_every_convention_round_trips_to_its_resolution(conv: TimeConvention) -> None:
    t = EPOCH_NS + np.array([0, 1_234_567, 49_999_999, 99_999_999], dtype=np.int64)
    head = int(t[-1]) if conv.reference == "header" else int(t[0])
    back, ok = to_ns(from_ns(t, head, conv), head, conv)
    assert ok.all() and back.dtype == np.int64
    assert np.abs(back - t).max() <= 1_000  # RESOLUTION_NS


@pytest.mark.parametrize("conv", CONVENTIONS, ids=lambda c: c.name)
def test_auto_recovers_every_written_convention(conv: TimeConvention) -> None:
    d = infer(conv.field, conv.dtype, _sweeps(conv))
    assert d.source == "auto" and d.convention == conv, d.line()
    assert d.evidence.span_ratio is not None and 0.9 < d.evidence.span_ratio < 1.05


@settings(max_examples=60, deadline=None)
@given(conv=st.sampled_from(CONVENTIONS),
       period_ms=st.sampled_from([25, 50, 100, 200, 1000]),
       span=st.floats(0.05, 1.0), points=st.integers(20, 400),
       t0=st.integers(1_000_000_000_000_000_000, 4_000_000_000_000_000_000),
       seed=st.integers(0, 1000))  # fmt: skip
def test_auto_recovers_the_convention_at_any_rate_span_and_epoch(
        conv: TimeConvention, period_ms: int, span: float, points: int, t0: int,
        seed: int) -> None:  # fmt: skip
    sweeps = _sweeps(conv, 4, period_ms * 1_000_000, points, t0, span, seed)
    d = infer(conv.field, conv.dtype, sweeps)
    assert d.convention == conv, d.line()


def test_livox_float64_absolute_ns_is_not_seconds_and_uint32_us_spans_100_ms() -> None:
    livox = DRIVERS["livox_ros_driver2"]
    assert infer("timestamp", "float64", _sweeps(livox)).convention == livox
    us = TimeConvention("t", "uint32", "us", "first_point")
    d = infer("t", "uint32", _sweeps(us))
    assert d.convention == us
    assert d.evidence.period_ns == pytest.approx(1e8) and d.evidence.span_ratio > 0.9


def test_no_convention_fits_a_constant_or_absent_time() -> None:
    conv = TimeConvention("t", "uint32", "ns", "first_point")
    flat = [SweepTimes(s.header_ns, np.zeros_like(s.values), 0.0) for s in _sweeps(conv)]
    d = infer("t", "uint32", flat)
    assert d.convention is None and d.source == "none" and "fits" in d.reason
    assert infer(None, "float64", flat).convention is None
    assert infer("t", "V", flat).convention is None
    one = _sweeps(conv, n=1)  # no period: no evidence for a unit
    assert infer("t", "uint32", one).convention is None


def test_span_ratio_and_header_offset_bounds_are_inclusive() -> None:
    lo, hi = SPAN_RATIO
    assert TimeEvidence(8, 1e8, lo, 0.0).fits() and TimeEvidence(8, 1e8, hi, 0.0).fits()
    assert not TimeEvidence(8, 1e8, np.nextafter(lo, 0), 0.0).fits()
    assert not TimeEvidence(8, 1e8, np.nextafter(hi, 9), 0.0).fits()
    assert TimeEvidence(8, 1e8, 1.0, HEADER_OFFSET_MAX).fits()
    assert not TimeEvidence(8, 1e8, 1.0, np.nextafter(HEADER_OFFSET_MAX, 9)).fits()
    assert not TimeEvidence(8, None).fits()


def test_unreadable_values_take_the_header_stamp_without_overflow() -> None:
    conv = TimeConvention("timestamp", "float64", "s", "absolute")
    v = np.array([EPOCH_NS / 1e9, np.nan, np.inf, 1e19, -1e300])
    with np.errstate(all="raise"):
        t, ok = to_ns(v, EPOCH_NS, conv)
    assert ok.tolist() == [True, False, False, False, False]
    assert (t[1:] == EPOCH_NS).all() and abs(int(t[0]) - EPOCH_NS) < 1_000
    big = np.array([2**64 - 1, 5], dtype=np.uint64)
    t, ok = to_ns(big, EPOCH_NS, TimeConvention("t", "uint64", "us", "first_point"))
    assert ok.tolist() == [False, True] and t.tolist() == [EPOCH_NS, EPOCH_NS + 5_000]


def test_header_and_first_point_decode_alike_and_units_scale() -> None:
    v = np.array([0, 10, 20], dtype=np.int64)
    for unit, scale in NS_PER_UNIT.items():
        a = to_ns(v, EPOCH_NS, TimeConvention("t", "int64", unit, "header"))[0]  # type: ignore[arg-type]
        b = to_ns(v, EPOCH_NS, TimeConvention("t", "int64", unit, "first_point"))[0]  # type: ignore[arg-type]
        assert (a == b).all() and (a - EPOCH_NS).tolist() == [0, 10 * scale, 20 * scale]


@pytest.mark.parametrize("dtype", ["int8", "uint8", "int16", "uint16"])
def test_a_field_too_narrow_for_a_time_gets_no_convention_whatever_its_values(dtype: str) -> None:
    """Was: a time field declared int16 over float64 bytes got a convention from noise. Values
    that do fit a unit (0..99 ms offsets over 10 Hz sweeps) still give none: the dtype cannot
    hold a point time to RESOLUTION_NS, so a fit there is not evidence."""
    sweeps = [SweepTimes(1_700_000_000_000_000_000 + i * 100_000_000,
                         np.arange(0, 100, dtype=np.float64), 0.0) for i in range(8)]
    d = infer("t", dtype, sweeps)
    assert d.convention is None and "cannot hold a point time" in d.reason
    assert infer("t", "uint32", [SweepTimes(s.header_ns, s.values * 1e6, 0.0)
                                 for s in sweeps]).convention is not None  # ns in uint32: held
