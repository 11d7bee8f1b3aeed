"""A camera's calibration over a recording: the CameraInfo in force at each image's stamp.

A driver may change a camera's resolution or intrinsics mid-recording (a restart with other
settings, binning). Every CameraInfo message is read as the images stream; where its model,
size, K or D differ from the one before, a new rectifier is built from it. An image follows the
latest CameraInfo at or before its own stamp (one before the first CameraInfo: the first). A
CameraInfo that cannot be used (bad K, unknown model) makes the images it covers rejects
(`calibration_mismatch`) until the next usable one: they are never rectified with another
camera's calibration.
"""

from __future__ import annotations

from bisect import bisect_right, insort
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.ingest.calib.camera import RawCamera, Rectifier, camera_from_info


def same_camera(a: RawCamera, b: RawCamera) -> bool:
    """Same model, size, K and D (the frame_id may differ: it does not move pixels)."""
    return (a.model, a.width, a.height) == (b.model, b.width, b.height) and bool(
        np.array_equal(a.K, b.K) and np.array_equal(a.D, b.D))  # fmt: skip


def describe(cam: RawCamera) -> str:
    """Size and focal lengths of a camera, for a note."""
    return f"{cam.width}x{cam.height} {cam.model} fx {cam.K[0, 0]:.6g} fy {cam.K[1, 1]:.6g}"


@dataclass
class CalibrationTrack:
    """One camera's calibrations by stamp: `first` (from the static pass), then each change.

    changes: (stamp_ns from which it holds, rectifier or the one-line reason it is unusable),
    sorted by stamp; `notes`: one line per change (for the ingest warnings).
    """

    camera: str
    first: Rectifier
    build: Callable[[RawCamera], Rectifier]
    changes: list[tuple[int, int, Rectifier | str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    _last: RawCamera | str | None = None

    def observe(self, info: Any, stamp_ns: int, where: str) -> None:
        """Take one CameraInfo message (header stamp `stamp_ns`) into account."""
        try:
            cam: RawCamera | str = camera_from_info(self.camera, info, where)
        except ValueError as err:
            cam = f"{err}"
        prev = self._last if self._last is not None else self.first.cam
        unchanged = (isinstance(cam, str) and cam == prev) or (
            isinstance(cam, RawCamera) and isinstance(prev, RawCamera) and same_camera(cam, prev))
        self._last = cam
        if unchanged:
            return
        item: Rectifier | str = cam if isinstance(cam, str) else self.build(cam)
        insort(self.changes, (stamp_ns, len(self.changes), item), key=lambda c: (c[0], c[1]))
        was = describe(prev) if isinstance(prev, RawCamera) else "an unusable one"
        now = describe(cam) if isinstance(cam, RawCamera) else f"unusable ({cam})"
        self.notes.append(f"{where}: CameraInfo of camera '{self.camera}' changes at stamp "
                          f"{stamp_ns} ns from {was} to {now}; its images follow the CameraInfo "
                          "in force at their own stamp")  # fmt: skip

    @property
    def usable(self) -> bool:
        """True when the last CameraInfo observed could be used (a camera, not a reason)."""
        return isinstance(self._last, RawCamera)

    def at(self, stamp_ns: int) -> Rectifier | str:
        """The rectifier in force at `stamp_ns`, or why the calibration there is unusable."""
        i = bisect_right(self.changes, stamp_ns, key=lambda c: c[0]) - 1
        return self.first if i < 0 else self.changes[i][2]
