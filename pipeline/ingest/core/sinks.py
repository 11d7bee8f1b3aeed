"""What every ingest pass writes to: the index writers and reject log (`Writers`), the
rectified images handed on (`CameraImage`, `ImageSink`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from packets.poses import F64
from pipeline.ingest.checks.rejects import RejectLog, Tally
from schemas.recording_index import IndexTableWriter


class CameraImage(NamedTuple):
    """One rectified output image, in stamp order per camera.

    frame: 0-based index among the camera's accepted images; stamp_ns: header stamp (int64 ns);
    image: (out_h, out_w, 3) uint8 RGB; K_out: (3, 3) float64 intrinsics of `image`.
    """

    camera: str
    frame: int
    stamp_ns: int
    image: npt.NDArray[np.uint8]
    K_out: F64


ImageSink = Callable[[CameraImage], None]


@dataclass
class Writers:
    """The streamed index tables and the reject log."""

    images: IndexTableWriter
    sweeps: IndexTableWriter
    odometry: IndexTableWriter
    rejects: RejectLog
    damage: IndexTableWriter

    @property
    def tally(self) -> Tally:
        """Messages read, kept and rejected per (bag file, topic)."""
        return self.rejects.tally
