"""The image check against neighbouring frames: a DC drift band or a one-frame offset is caught,
frames of a moving camera are not."""

from __future__ import annotations

import cv2
import numpy as np
import simplejpeg
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.checks.image_checks import (
    NOISE_FLOOR,
    YCC,
    Cells,
    PairMemo,
    band_steps,
    cell_means,
    cell_size,
    drift_problem,
)

H, W, STEP_NS = 160, 240, 100_000_000
TEXTURE = cv2.GaussianBlur(np.random.default_rng(0).uniform(0, 255, (H + 40, W + 80, 3)),
                           (0, 0), 3).astype(np.uint8)  # fmt: skip


def frame(i: int) -> np.ndarray:
    """Frame i of a camera panning 2 px and tilting 1 px per frame over a texture, RGB."""
    return np.ascontiguousarray(TEXTURE[i % 40 : i % 40 + H, 2 * i : 2 * i + W])


def jpeg_cells(rgb: np.ndarray, i: int) -> Cells:
    """Cells of an RGB frame after a JPEG round trip (quality 90, 4:2:0)."""
    data = simplejpeg.encode_jpeg(rgb, quality=90, colorsubsampling="420")
    decoded = simplejpeg.decode_jpeg(data, "RGB")
    return Cells(i * STEP_NS, cell_means(decoded, cell_size("420", 1)))


def drifted(rgb: np.ndarray, mcu: int, delta: np.ndarray) -> np.ndarray:
    """The frame with every 16x16 MCU from raster index `mcu` on offset by `delta` (RGB)."""
    out = rgb.astype(np.int16)
    cols = W // 16
    r, c = divmod(mcu, cols)
    out[16 * r : 16 * r + 16, 16 * c :] += delta.astype(np.int16)
    out[16 * (r + 1) :] += delta.astype(np.int16)
    return np.clip(out, 0, 255).astype(np.uint8)


def check(cells: Cells, neighbours: list[Cells]) -> str | None:
    """The check with the default thresholds."""
    return drift_problem(cells, neighbours, 10.0, 10.0, 0.5)


def test_moving_camera_passes() -> None:
    cells = [jpeg_cells(frame(i), i) for i in range(12)]
    for i, c in enumerate(cells):
        assert check(c, [cells[j] for j in (i - 1, i + 1) if 0 <= j < len(cells)]) is None


@settings(max_examples=40, deadline=None, derandomize=True)
@given(i=st.integers(2, 10), row=st.integers(1, H // 16 - 2), col=st.integers(0, W // 16 - 1),
       level=st.sampled_from([-40, -15, 15, 40]), colour=st.booleans())  # fmt: skip
def test_drift_band_caught(i: int, row: int, col: int, level: int, colour: bool) -> None:
    """An offset of >= 15 grey levels from one MCU to the end of the image (a flipped DC bit
    decoded without an error) is refused; before the check every such image was cached."""
    delta = np.array([level, -level, 0] if colour else [level] * 3)
    bad = jpeg_cells(drifted(frame(i), row * (W // 16) + col, delta), i)
    near = [jpeg_cells(frame(i - 1), i - 1), jpeg_cells(frame(i + 1), i + 1)]
    found = check(bad, near)
    assert found and "damaged JPEG data" in found
    assert check(near[0], [jpeg_cells(frame(i - 2), i - 2), bad]) is None  # its good neighbour


def test_whole_frame_offset_caught_and_far_frames_ignored() -> None:
    bad = jpeg_cells(drifted(frame(5), 0, np.array([0, 30, 0])), 5)
    near = [jpeg_cells(frame(4), 4), jpeg_cells(frame(6), 6)]
    assert check(bad, near)
    far = [Cells(c.stamp_ns - 10**9, c.means) for c in near[:1]]
    assert check(bad, far) is None  # no neighbour within 0.5 s: not judged


# The check sorts once where it can and compares a pair of frames once (`PairMemo`); its values
# must be those of the plain formulation below, bit for bit.


def _ref_band_steps(img: np.ndarray, other: np.ndarray, z_max: float) -> np.ndarray:
    d = img.astype(np.float64) - other.astype(np.float64)
    rows = d.shape[1]
    out = np.zeros((3, max(rows - 1, 0)))
    if rows < 2:
        return out
    for c in range(3):
        m = np.array([np.median(d[c, r]) for r in range(rows)])
        noise = 1.4826 * float(np.median(np.abs(np.diff(m)))) / np.sqrt(2) + NOISE_FLOOR
        for r in range(1, rows):
            below, above = np.median(m[r:]), np.median(m[:r])
            z = (below - above) / noise
            out[c, r - 1] = np.clip(z, -z_max, z_max)
            if abs(z) > z_max:
                spread = float(np.median(np.abs(m[r:] - below)))
                out[c, r - 1] = (below - above) / (noise + spread)
    return out


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), rows=st.integers(1, 24), cols=st.integers(1, 40),
       ties=st.booleans(), band=st.integers(-1, 23), level=st.sampled_from([0.0, 3.0, 40.0]),
       z_max=st.sampled_from([0.0, 3.0, 10.0, np.inf]))  # fmt: skip
def test_band_steps_equal_reference(seed: int, rows: int, cols: int, ties: bool, band: int,
                                    level: float, z_max: float) -> None:  # fmt: skip
    rng = np.random.default_rng(seed)
    def draw() -> np.ndarray:
        if ties:
            return rng.integers(0, 4, (3, rows, cols)).astype(np.float32)
        return (rng.normal(128, 20, (3, rows, cols))).astype(np.float32)

    a, b = draw(), draw()
    if 0 <= band < rows:
        a[int(rng.integers(0, 3)), band:] += level
    got = band_steps(a, b, z_max)
    assert np.array_equal(got, _ref_band_steps(a, b, z_max))
    assert np.array_equal(band_steps(b, a, z_max), -got)  # what PairMemo relies on


@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 120), w=st.integers(1, 120),
       cell=st.tuples(st.integers(1, 16), st.integers(1, 16)))  # fmt: skip
def test_cell_means_equal_einsum(seed: int, h: int, w: int, cell: tuple[int, int]) -> None:
    rgb = np.random.default_rng(seed).integers(0, 256, (h + cell[0], w + cell[1], 3), np.uint8)
    ch, cw = cell
    hh, ww = rgb.shape[0] // ch, rgb.shape[1] // cw
    crop = np.ascontiguousarray(rgb[: hh * ch, : ww * cw]).astype(np.float32)
    sums = cv2.resize(crop, (ww, hh), interpolation=cv2.INTER_AREA).reshape(hh, ww, 3)
    want = np.einsum("ij,hwj->ihw", YCC, sums)
    got = cell_means(rgb, cell)
    assert got.dtype == want.dtype and np.array_equal(got, want)


def test_memo_gives_the_verdicts_of_fresh_comparisons() -> None:
    """A stream judged with one PairMemo (frames compared once, read back negated) gets the
    verdicts and lines of the same stream judged with no memory, damaged frames included."""
    rng = np.random.default_rng(5)
    cells = []
    for i in range(30):
        rgb = frame(i)
        if i % 7 == 3:
            rgb = drifted(rgb, int(rng.integers(0, (H // 16) * (W // 16))), np.array([30, -30, 0]))
        elif i % 7 == 5:
            rgb = np.clip(rgb.astype(np.int16) + 25, 0, 255).astype(np.uint8)
        cells.append(jpeg_cells(rgb, i))
    memo, last_ok, found = PairMemo(size=4), None, []
    for i, c in enumerate(cells):
        after = cells[i + 1] if i + 1 < len(cells) else None
        near = [n for n in (last_ok, after) if n is not None] if last_ok is not None else []
        got = drift_problem(c, near, 10.0, 10.0, 0.5, memo)
        assert got == drift_problem(c, near, 10.0, 10.0, 0.5)
        found.append(got)
        last_ok = c if got is None else last_ok
    assert sum(f is not None for f in found) >= 4  # the damaged frames were judged as such
