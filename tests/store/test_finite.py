"""all_finite: agrees with np.isfinite for every float width, at any position and shape."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from store.finite import BLOCK, all_finite

DTYPES = [np.float16, np.float32, np.float64]


@settings(max_examples=200, deadline=None)
@given(data=st.data(), dtype=st.sampled_from(DTYPES))
def test_agrees_with_isfinite(data: st.DataObject, dtype: type) -> None:
    arr = data.draw(hnp.arrays(dtype, hnp.array_shapes(min_dims=1, max_dims=4, max_side=6),
                               elements=hnp.from_dtype(np.dtype(dtype), allow_nan=True,
                                                       allow_infinity=True)))
    assert all_finite(arr) == bool(np.isfinite(arr).all())


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", [0, BLOCK - 1, BLOCK, 3 * BLOCK + 5])
def test_finds_one_bad_element_in_any_block(dtype: type, bad: float, where: int) -> None:
    arr = np.full(3 * BLOCK + 7, np.finfo(dtype).max, dtype)  # the largest finite value passes
    assert all_finite(arr)
    arr[where] = bad
    assert not all_finite(arr)
    assert not all_finite(arr.reshape(-1, 1)[::-1])  # non-contiguous views too


def test_subnormals_and_signed_zero_are_finite() -> None:
    arr = np.array([0.0, -0.0, np.finfo(np.float16).smallest_subnormal], np.float16)
    assert all_finite(arr)


def test_refuses_non_float() -> None:
    with pytest.raises(TypeError, match="float16/32/64"):
        all_finite(np.zeros(3, np.int32))  # type: ignore[arg-type]
