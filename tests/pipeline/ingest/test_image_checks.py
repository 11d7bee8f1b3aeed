"""The image check against neighbouring frames: a DC drift band or a one-frame offset is caught,
frames of a moving camera are not."""

from __future__ import annotations

import cv2
import numpy as np
import simplejpeg
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.ingest.image_checks import Cells, cell_means, cell_size, drift_problem

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
