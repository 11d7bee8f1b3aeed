"""Plausibility of a decoded camera image against its neighbours in time (pure numpy).

A flipped bit in a JPEG's entropy-coded data that libjpeg decodes without a warning mostly
changes one DC difference: every block decoded after it is offset by a constant in one colour
component, a band from that MCU to the bottom of the image (JPEG codes DC values as
differences in raster order). Frame to frame at camera rate the scene changes little, so:

- `band_steps`: per colour component (YCbCr) and MCU row, the median over the row of the
  image minus a neighbour (per-MCU means); a damaged image shows a step between the rows
  above and below some boundary, large against the row-to-row noise of that profile;
- `blip`: the whole image offset in one component against both neighbours, which agree with
  each other (the drift began in the first MCU row).

An image is refused only when it disagrees the same way with each neighbour (within
`max_gap_s`), so a damaged neighbour does not cost a good image. Not caught: a flip that
changes AC coefficients only (one 8x8 block differs: image content, not an anomaly), and DC
offsets of about a grey level or less.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
MCU_PX = {"444": (8, 8), "422": (8, 16), "440": (16, 8), "420": (16, 16), "411": (8, 32),
          "Gray": (8, 8)}  # fmt: skip
"""MCU (height, width) in pixels by the chroma subsampling simplejpeg reports."""
COMPONENTS = ("Y", "Cb", "Cr")
NOISE_FLOOR = 0.3
"""Grey levels added to the step noise (a flat profile has none)."""
YCC = np.array([[0.299, 0.587, 0.114], [-0.1687, -0.3313, 0.5], [0.5, -0.4187, -0.0813]],
               dtype=np.float32)  # fmt: skip


@dataclass(frozen=True)
class Cells:
    """Per-MCU mean colour (3, rows, cols) float32 in YCbCr of one image, and its stamp (ns)."""

    stamp_ns: int
    means: F32


def cell_means(rgb: U8, cell_hw: tuple[int, int]) -> F32:
    """(3, H // ch, W // cw) mean Y, Cb, Cr over each cell of an (H, W, 3) RGB image."""
    ch, cw = max(1, cell_hw[0]), max(1, cell_hw[1])
    h, w = rgb.shape[0] // ch, rgb.shape[1] // cw
    crop = np.ascontiguousarray(rgb[: h * ch, : w * cw]).astype(np.float32)
    sums = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA).reshape(h, w, 3)  # block means
    s0, s1, s2 = sums[..., 0], sums[..., 1], sums[..., 2]
    # YCC @ rgb per cell, summed left to right in float32 (what einsum("ij,hwj->ihw") does)
    return np.stack([YCC[i, 0] * s0 + YCC[i, 1] * s1 + YCC[i, 2] * s2 for i in range(3)])


def cell_size(subsampling: str, reduction: int) -> tuple[int, int]:
    """MCU size in pixels of an image decoded at 1/`reduction` (at least 1 x 1)."""
    mh, mw = MCU_PX.get(subsampling, (8, 8))
    return max(1, mh // reduction), max(1, mw // reduction)


def _row_medians(d: F64) -> F64:
    """(...,) median over the last axis of d (..., n), n >= 1; equal to np.median(d, axis=-1)
    (the mean of the two middle values) for finite d, by one sort (np.median's partition
    along a short axis is several times slower)."""
    n = d.shape[-1]
    if n == 0 or not bool(np.isfinite(d).all()):
        return np.asarray(np.median(d, axis=-1), dtype=np.float64)
    s = np.sort(d, axis=-1)
    return np.asarray((s[..., (n - 1) // 2] + s[..., n // 2]) / 2, dtype=np.float64)


def _part_medians(m: F64) -> tuple[F64, F64]:
    """(..., rows - 1) medians of m[..., r:] (below) and of m[..., :r] (above) for
    r = 1 .. rows - 1, for each profile of m (..., rows), by one sort per profile."""
    rows = m.shape[-1]
    order = np.argsort(m, axis=-1, kind="stable")
    vals = np.take_along_axis(m, order, -1)
    r = np.arange(1, rows)[:, None]
    out = []
    for below in (True, False):
        # (..., rows - 1, rows): whether the k-th smallest value lies inside part r
        inside = order[..., None, :] >= r if below else order[..., None, :] < r
        n = (rows - r[:, 0]) if below else r[:, 0]
        seen = np.cumsum(inside, axis=-1)
        lo = np.argmax(seen > ((n - 1) // 2)[:, None], axis=-1)
        hi = np.argmax(seen > (n // 2)[:, None], axis=-1)
        pair = np.take_along_axis(vals, lo, -1) + np.take_along_axis(vals, hi, -1)
        out.append(np.asarray(pair / 2, dtype=np.float64))
    return out[0], out[1]


def _medians_f32(x: F32) -> F32:
    """(k,) median of each row of x (k, n) float32, n >= 1, finite; equal to np.median of the
    row (the float32 mean of the two middle values), by one sort."""
    n = x.shape[-1]
    s = np.sort(x, axis=-1)
    return np.asarray((s[..., (n - 1) // 2] + s[..., n // 2]) / np.float32(2), dtype=np.float32)


def band_steps(img: F32, other: F32, z_max: float = 0.0) -> F64:
    """(3, rows - 1) signed step z of the row profile of img - other at each MCU-row boundary.

    Profile m[r] = median over row r of the per-cell difference; at boundary R the step is
    median(m[R:]) - median(m[:R]) over (noise + spread of m[R:]), noise being the robust
    row-to-row scatter of m. A constant offset of every row from R on gives a large value.
    The spread is computed only where the step over the noise alone exceeds `z_max` (it can
    only lower the value); elsewhere that bound, clipped to `z_max`, is returned.
    band_steps(other, img) is exactly -band_steps(img, other) (`PairMemo` relies on it).
    """
    d = img.astype(np.float64) - other.astype(np.float64)
    rows = d.shape[1]
    out = np.zeros((3, max(rows - 1, 0)))
    if rows < 2:
        return out
    profiles = _row_medians(d)  # (3, rows)
    noise = 1.4826 * _row_medians(np.abs(np.diff(profiles, axis=1))) / np.sqrt(2) + NOISE_FLOOR
    below, above = _part_medians(profiles)
    step = below - above
    z = step / noise[:, None]
    out[:] = np.clip(z, -z_max, z_max)
    for c, r in np.argwhere(np.abs(z) > z_max):
        spread = float(np.median(np.abs(profiles[c, r + 1 :] - below[c, r])))
        out[c, r] = step[c, r] / (noise[c] + spread)
    return out


_Key = tuple[int, int, float | None]
"""id of the image's cells, id of the neighbour's, the step bound (None: offsets)."""


class PairMemo:
    """The last few comparisons of two frames' cells, by the identity of the two `Cells`.

    A frame is judged against the next one, and that next one later against it (when it was
    accepted): the second comparison is the first negated exactly (`band_steps`; a median of
    negated values is the negated median), so it is read back instead of computed again.
    Holds references to the cells it keys on, so an id is never reused while remembered;
    `size` comparisons of each kind (two a judged frame: enough for about 15 cameras judged in
    turn), the oldest forgotten first.
    """

    def __init__(self, size: int = 32) -> None:
        self.size = size
        self._steps: dict[_Key, tuple[Cells, Cells, F64]] = {}
        self._offsets: dict[_Key, tuple[Cells, Cells, F64]] = {}

    def steps(self, img: Cells, other: Cells, z_max: float) -> F64:
        """band_steps(img.means, other.means, z_max)."""
        return self._get(self._steps, img, other,
                         lambda: band_steps(img.means, other.means, z_max), z_max)  # fmt: skip

    def offsets(self, img: Cells, other: Cells) -> F64:
        """(3,) median over the cells of img - other per component (float32 differences)."""
        def compute() -> F64:
            diff = (img.means - other.means).reshape(img.means.shape[0], -1)
            if diff.shape[1] == 0 or not bool(np.isfinite(diff).all()):
                return np.array([float(np.median(diff[c])) for c in range(diff.shape[0])])
            return _medians_f32(diff).astype(np.float64)

        return self._get(self._offsets, img, other, compute, None)

    def _get(self, table: dict[_Key, tuple[Cells, Cells, F64]], a: Cells, b: Cells,
             compute: Callable[[], F64], tag: float | None) -> F64:  # fmt: skip
        """The value for (a, b): remembered, the negation of (b, a)'s, or computed."""
        key = (id(a), id(b), tag)
        hit = table.get(key)
        if hit is not None:
            return hit[2]
        rev = table.get((id(b), id(a), tag))
        value = -rev[2] if rev is not None else compute()
        table[key] = (a, b, value)
        while len(table) > self.size:
            del table[next(iter(table))]
        return value


def step_problem(img: Cells, neighbours: list[Cells], z_max: float,
                 memo: PairMemo | None = None) -> str | None:  # fmt: skip
    """One line when img steps away from every neighbour at the same MCU row (same sign)."""
    if not neighbours or img.means.shape[1] < 3:
        return None
    memo = memo or PairMemo()
    steps = [memo.steps(img, n, z_max) for n in neighbours]
    if any(s.shape != steps[0].shape for s in steps):
        return None
    sign = np.sign(steps[0])
    agree = np.all([np.sign(s) == sign for s in steps], axis=0)
    z = np.min([np.abs(s) for s in steps], axis=0) * agree
    if float(z.max()) <= z_max:
        return None
    c, r = np.unravel_index(int(np.argmax(z)), z.shape)
    return (f"colour component {COMPONENTS[int(c)]} steps from MCU row {int(r) + 1} "
            f"down against the {len(neighbours)} neighbouring frame(s) (z {float(z.max()):.1f} "
            f"> {z_max:g}): damaged JPEG data decoded without an error")  # fmt: skip


def blip_problem(img: Cells, neighbours: list[Cells], levels: float,
                 memo: PairMemo | None = None) -> str | None:  # fmt: skip
    """One line when img is offset by more than `levels` grey levels in one component against
    both neighbours, which agree with each other within a quarter of that offset."""
    if len(neighbours) != 2 or any(n.means.shape != img.means.shape for n in neighbours):
        return None
    memo = memo or PairMemo()
    a, b = neighbours
    da_all, db_all = memo.offsets(img, a), memo.offsets(img, b)
    for c in range(3):
        da, db = float(da_all[c]), float(db_all[c])
        off = min(abs(da), abs(db))
        if not (da * db > 0 and off > levels):
            continue
        ab = abs(float(np.median(a.means[c] - b.means[c])))
        if ab < off / 4:
            return (f"colour component {COMPONENTS[c]} offset by {off:.1f} grey levels "
                    f"against both neighbouring frames (> {levels:g}, they differ by {ab:.1f}): "
                    "damaged JPEG data decoded without an error")  # fmt: skip
    return None


def drift_problem(img: Cells, neighbours: list[Cells], z_max: float, blip_levels: float,
                  max_gap_s: float, memo: PairMemo | None = None) -> str | None:  # fmt: skip
    """The image's disagreement with its neighbours within `max_gap_s`, in one line, or None.

    A neighbour of another cell grid (the camera's resolution changed between them) is not
    compared. `memo` (one per stream) reuses comparisons already made in the other direction;
    the result is the same without it."""
    near = [n for n in neighbours if abs(n.stamp_ns - img.stamp_ns) <= max_gap_s * 1e9
            and n.means.shape == img.means.shape]  # fmt: skip
    memo = memo or PairMemo()
    return (step_problem(img, near, z_max, memo)
            or blip_problem(img, near, blip_levels, memo))
