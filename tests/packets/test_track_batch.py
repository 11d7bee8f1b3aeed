"""packets.track_batch: many stamps read at once equal Track.at's reading, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from packets.reprojection_consistency import Track
from packets.track_batch import BatchTrack

T0 = 1_700_000_000_123_456_789


def _track(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = T0 + np.cumsum(rng.integers(1, 10**8, n))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    T[:, :3, 3] = rng.normal(size=(n, 3)) * 10
    return t, T


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), n=st.integers(2, 40), as_float=st.booleans())
def test_at_many_equals_track_at_bit_for_bit(seed: int, n: int, as_float: bool) -> None:
    t, T = _track(seed, n)
    rng = np.random.default_rng(seed + 1)
    ints = [int(x) for x in rng.integers(t[0] - 10**7, t[-1] + 10**7, 25)]
    stamps = [x - 0.05e9 * float(rng.random()) for x in ints] if as_float else ints
    got, inside = BatchTrack(t, T).at_many(stamps)
    track = Track(t, T)
    for k, s in enumerate(stamps):
        ref = track.at(s)
        assert bool(inside[k]) == (ref is not None)
        if ref is not None:
            assert np.array_equal(got[k], ref)


def test_the_span_is_closed_at_both_ends() -> None:
    t, T = _track(3, 5)
    stamps = [int(t[0]) - 1, int(t[0]), int(t[-1]), int(t[-1]) + 1]
    got, inside = BatchTrack(t, T).at_many(stamps)
    assert inside.tolist() == [False, True, True, False]
    assert np.array_equal(got[0], np.eye(4)) and np.array_equal(got[3], np.eye(4))
    np.testing.assert_allclose(got[1], T[0], atol=1e-12)
    np.testing.assert_allclose(got[2], T[-1], atol=1e-12)


def test_no_stamps_and_a_bad_track() -> None:
    t, T = _track(4, 3)
    got, inside = BatchTrack(t, T).at_many([])
    assert got.shape == (0, 4, 4) and inside.shape == (0,)
    with pytest.raises(ValueError, match="strictly increasing"):
        BatchTrack(t[::-1], T)
