"""The `image_drift` check of a stream of images, for every source: each image held until its
camera's next image is decoded, then judged (`image_checks.drift_problem`) against that next
image and the camera's last accepted one.

An image is judged against both neighbours, or against the last accepted one alone; never
against an unjudged image alone (a damaged next frame would cost a good image). Its reject
wording is the problem line itself (`image_checks`), reason `corrupt_jpeg`. Pure bookkeeping
over `Cells` (per-MCU means, float32 YCbCr): no I/O.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import simplejpeg

from pipeline.ingest.checks.image_checks import (
    Cells,
    PairMemo,
    cell_means,
    cell_size,
    drift_problem,
)
from schemas.config import ChecksConfig

IMAGE_CHECKS = ("image_drift",)
"""The plausibility checks of an image stream (`check_fit.FitGate` names)."""

Judged = tuple[Any, "str | None"]
"""An image let go by the hold: its item and the drift problem (None: plausible)."""


def drift_on(checks: ChecksConfig) -> bool:
    """Whether the image checks run (checks on and one of their thresholds set)."""
    return checks.enabled and bool(checks.image_step_z or checks.image_blip_levels)


def jpeg_cells(data: npt.NDArray[np.uint8], decoded: npt.NDArray[np.uint8], stamp: int,
               reduction: int) -> Cells:  # fmt: skip
    """The cells of a JPEG (its bytes `data`) decoded at 1/`reduction` to RGB `decoded`: one
    per MCU of its chroma subsampling."""
    sub = simplejpeg.decode_jpeg_header(data.tobytes())[3]
    return Cells(stamp, cell_means(decoded, cell_size(sub, reduction)))


@dataclass
class DriftHold:
    """The held images and last accepted cells of the cameras of a pass, by key (a camera).

    `push` holds an image and returns the camera's previous one judged; `pop` judges the held
    one against the last accepted image alone (the camera's next image is not judged, or the
    stream ends); `flush` does so for every camera, by key. `active(item)` says whether the
    check still runs for that image's stream (`FitGate.active`); an inactive check judges
    nothing (problem None)."""

    checks: ChecksConfig
    active: Callable[[Any], bool]
    memo: PairMemo = field(default_factory=PairMemo)  # frame comparisons made
    held: dict[str, tuple[Any, Cells]] = field(default_factory=dict)
    last_ok: dict[str, Cells] = field(default_factory=dict)

    def push(self, key: str, item: Any, cells: Cells) -> list[Judged]:
        """Hold `item` (its `cells`); the camera's previous image, judged with `cells` after."""
        out = self._judge(key, self.held.pop(key), cells) if key in self.held else []
        self.held[key] = (item, cells)
        return out

    def pop(self, key: str) -> list[Judged]:
        """The camera's held image, judged against its last accepted one alone ([] if none)."""
        return self._judge(key, self.held.pop(key), None) if key in self.held else []

    def flush(self) -> list[Judged]:
        """Every held image, by key, judged against the last accepted one (the end)."""
        return [j for key in sorted(self.held) for j in self.pop(key)]

    def _judge(self, key: str, held: tuple[Any, Cells], after: Cells | None) -> list[Judged]:
        """One held image's verdict; a plausible one becomes the camera's last accepted."""
        item, cells = held
        before = self.last_ok.get(key)
        near = [n for n in (before, after) if n is not None] if before is not None else []
        problem = None
        if self.active(item):
            c = self.checks
            problem = drift_problem(cells, near, c.image_step_z or np.inf,
                                    c.image_blip_levels or np.inf, c.image_max_gap_s,
                                    self.memo)  # fmt: skip
        if problem is None:
            self.last_ok[key] = cells
        return [(item, problem)]
