"""Fast all-finite check of IEEE float arrays, the cache's last guard against NaN and Inf.

A float is NaN or +-Inf exactly when its exponent bits are all ones. Viewing the array as
unsigned integers of the same width and taking the maximum of (bits & exponent mask) over
cache-sized blocks needs no float arithmetic and no full-size temporary: faster than
`np.isfinite(np.add.reduce(x, dtype=float64))` on a shard of latents (docs/benchmarks.md,
'Design measurements').
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_EXPONENT = {2: (np.uint16, 0x7C00), 4: (np.uint32, 0x7F80_0000),
             8: (np.uint64, 0x7FF0_0000_0000_0000)}
BLOCK = 1 << 18  # elements per block: 0.5-2 MB, stays in L2


def all_finite(data: NDArray[np.floating]) -> bool:
    """True when no element of a float16/32/64 array of any shape is NaN or +-Inf."""
    if data.dtype.kind != "f" or data.dtype.itemsize not in _EXPONENT:
        raise TypeError(f"all_finite needs float16/32/64, got {data.dtype}")
    utype, mask = _EXPONENT[data.dtype.itemsize]
    bits = np.ascontiguousarray(data).reshape(-1).view(utype)
    buf = np.empty(min(BLOCK, bits.size), utype)
    expo = utype(mask)
    for start in range(0, bits.size, BLOCK):
        block = bits[start:start + BLOCK]
        out = buf[:block.size]
        np.bitwise_and(block, expo, out=out)  # type: ignore[call-overload]
        if out.max() == expo:
            return False
    return True
