"""Mergeable channel statistics: merging parts equals the whole, stable at large offsets."""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from packets.running_stats import ChannelStats, merge_all


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
    np.testing.assert_array_equal(back.m2, stats.m2)
