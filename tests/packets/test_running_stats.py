"""Mergeable channel statistics: merging parts equals the whole, stable at large offsets."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.running_stats import ChannelStats, merge_all
from schemas.errors import DataError


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 200),
    cuts=st.lists(st.integers(0, 200), max_size=5),
    offset=st.sampled_from([0.0, 1e3, 1e6]),
    seed=st.integers(0, 2**16),
)
def test_merge_of_parts_equals_whole(n: int, cuts: list[int], offset: float, seed: int) -> None:
    x = np.random.default_rng(seed).normal(offset, 1.0, size=(n, 3))
    bounds = sorted({0, n, *[min(c, n) for c in cuts]})
    parts = [ChannelStats.of(x[a:b]) for a, b in itertools.pairwise(bounds)]
    merged = merge_all(parts)
    whole = ChannelStats.of(x)
    assert merged.count == whole.count == n
    # against numpy directly (population variance, ddof=0)
    for stats in (merged, whole):
        np.testing.assert_allclose(stats.mean, x.mean(0), rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(stats.variance, x.var(0), rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(stats.m2, x.var(0) * n, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(stats.std, np.maximum(x.std(0), 1e-6), rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(stats.minimum, x.min(0))
        np.testing.assert_array_equal(stats.maximum, x.max(0))
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(merged.variance, whole.variance, rtol=1e-6, atol=1e-9)
    assert np.all(merged.variance >= 0)


def test_constant_channel_has_zero_variance() -> None:
    stats = ChannelStats.of(np.full((1000, 2), 1e4))
    assert np.all(stats.variance == 0.0)
    assert np.all(stats.std == 1e-6)


def test_dict_round_trip() -> None:
    stats = ChannelStats.of(np.arange(12.0).reshape(4, 3))
    back = ChannelStats.from_dict(stats.to_dict())
    assert back.count == 4
    for name in ("mean", "m2", "minimum", "maximum"):
        np.testing.assert_array_equal(getattr(back, name), getattr(stats, name))
        assert getattr(back, name).dtype == np.float64


def test_from_dict_gives_float64_from_integer_lists() -> None:
    """JSON may hold whole numbers as integers; the statistics stay (C,) float64."""
    back = ChannelStats.from_dict({"count": [2], "mean": [1, 2], "m2": [0, 8], "min": [1, 0],
                                   "max": [1, 4]})
    for name, want in (("mean", [1, 2]), ("m2", [0, 8]), ("minimum", [1, 0]), ("maximum", [1, 4])):
        got = getattr(back, name)
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(back.variance, [0.0, 4.0])


def test_empty_statistics_are_the_merge_identity() -> None:
    empty = ChannelStats.empty(3)
    assert empty.count == 0
    np.testing.assert_array_equal(empty.mean, np.zeros(3))
    np.testing.assert_array_equal(empty.m2, np.zeros(3))
    np.testing.assert_array_equal(empty.minimum, np.full(3, np.inf))
    np.testing.assert_array_equal(empty.maximum, np.full(3, -np.inf))
    for arr in (empty.mean, empty.m2, empty.minimum, empty.maximum):
        assert arr.dtype == np.float64 and arr.shape == (3,)
    empty.mean[0] = 5.0  # mean and m2 are separate arrays
    assert empty.m2[0] == 0.0
    some = ChannelStats.of(np.array([[1.0, -2.0, 3.0], [3.0, 2.0, 3.0]]))
    for merged in (empty.merge(some), some.merge(ChannelStats.empty(3))):
        assert merged.count == 2
        np.testing.assert_array_equal(merged.minimum, [1.0, -2.0, 3.0])
        np.testing.assert_array_equal(merged.maximum, [3.0, 2.0, 3.0])
        np.testing.assert_array_equal(merged.variance, [1.0, 4.0, 0.0])


def test_no_samples_give_empty_statistics_and_no_channels_are_counted() -> None:
    none = ChannelStats.of(np.zeros((0, 2)))
    assert none.count == 0
    np.testing.assert_array_equal(none.minimum, [np.inf, np.inf])
    np.testing.assert_array_equal(none.maximum, [-np.inf, -np.inf])
    np.testing.assert_array_equal(none.variance, [0.0, 0.0])
    no_channels = ChannelStats.of(np.zeros((4, 0)))
    assert no_channels.count == 4 and no_channels.mean.shape == (0,)


def test_integer_samples_give_float64_statistics() -> None:
    stats = ChannelStats.of(np.array([[1, -7], [2, 5], [4, 5]], dtype=np.int32))
    for arr in (stats.mean, stats.m2, stats.minimum, stats.maximum):
        assert arr.dtype == np.float64
    np.testing.assert_array_equal(stats.minimum, [1.0, -7.0])
    np.testing.assert_array_equal(stats.maximum, [4.0, 5.0])


def test_one_sample_has_zero_variance_and_floored_std() -> None:
    stats = ChannelStats.of(np.array([[2.5, -1.0]]))
    np.testing.assert_array_equal(stats.variance, [0.0, 0.0])
    np.testing.assert_array_equal(stats.std, [1e-6, 1e-6])


@pytest.mark.parametrize(("x", "message"), [
    (np.zeros(3), r"expected samples of shape \(N, C\), got \(3,\)"),
    (np.array([[1.0, np.nan]]), r"^samples contain NaN or Inf$"),
    (np.array([[np.inf, 0.0]]), r"^samples contain NaN or Inf$"),
])
def test_bad_samples_are_refused_with_their_reason(x: np.ndarray, message: str) -> None:
    with pytest.raises(DataError, match=message):
        ChannelStats.of(x)


def test_merging_nothing_is_refused() -> None:
    with pytest.raises(DataError, match=r"^no statistics to merge$"):
        merge_all([])


def test_merge_all_of_odd_counts_keeps_every_part() -> None:
    """Three and five parts: the last part of an odd level is carried up, not dropped."""
    rows = np.arange(10.0).reshape(5, 2)
    for k in (1, 3, 5):
        merged = merge_all([ChannelStats.of(rows[i:i + 1]) for i in range(k)])
        assert merged.count == k
        np.testing.assert_array_equal(merged.maximum, rows[k - 1])
        np.testing.assert_allclose(merged.mean, rows[:k].mean(0), rtol=1e-15)
