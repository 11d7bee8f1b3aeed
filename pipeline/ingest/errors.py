"""The errors the readers raise on bad input: all data errors (permanent, never retried).

Most become rejects (a row of `rejects.parquet` naming file, topic and stamp) where they are
caught; MissingTransformError stops the recording (no camera without its chain).
"""

from __future__ import annotations

from schemas.errors import DataError
from schemas.recording_index import Reason


class CorruptImageError(DataError):
    """A compressed image that does not decode to the expected size."""


class UnsupportedImageError(DataError):
    """A camera message of an encoding or format m3gd does not read (not damage)."""


class CalibrationMismatchError(DataError):
    """An image that does not fit its own CameraInfo (another size, an unusable calibration)."""


class MissingTransformError(DataError):
    """No chain of TF edges connects two frames."""


class BadPoseError(DataError):
    """An odometry pose that is NaN, a zero quaternion or absurdly far away."""


class RowReject(DataError):
    """A row refused by its handler: reason, and the file it lives in."""

    def __init__(self, reason: Reason, file: str, detail: str) -> None:
        """Keep the reason code and the file beside the message."""
        super().__init__(detail)
        self.reason, self.file = reason, file

    def __reduce__(self) -> tuple[object, ...]:
        """Pickled by its fields (the constructor takes more than the message)."""
        return (type(self), (self.reason, self.file, str(self)))
