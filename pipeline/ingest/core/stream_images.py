"""Images of the streaming pass: decode and rectify one image message (JPEG, PNG or raw,
following its camera's CameraInfo) into its index row and what keeping it does (`emit`: the
image to the sink), with its cells for the drift check; its topic's gated pass
(`gated_pass.GatedPass`) holds it for that check, then indexes or rejects it."""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.ingest.checks.image_drift import drift_on, jpeg_cells
from pipeline.ingest.core.gated_pass import Indexed, emit_image
from pipeline.ingest.core.stream_state import StreamState
from pipeline.ingest.core.sweep_stream import message_where
from pipeline.ingest.errors import (
    CalibrationMismatchError,
    CorruptImageError,
    RowReject,
    UnsupportedImageError,
)
from pipeline.ingest.sources.bags import Message
from pipeline.ingest.sources.image_decode import image_kind
from schemas.recording_index import Reason


def image_message(msg: Message, obj: Any, stamp: int, camera: str,
                  st: StreamState) -> Indexed | None:  # fmt: skip
    """Rectify one image message into its index row (None: the camera has no CameraInfo,
    reported once by read_static); RowReject for a corrupt, unsupported or mismatched image.

    With the image checks on, a JPEG that no verified checksum vouches for carries its cells:
    it is held until the camera's next image is decoded, then judged against it and the last
    accepted image (`image_drift`).
    """
    rect = st.rectifier_at(camera, stamp)
    if rect is None:
        return None
    where = f"{msg.file}: {msg.topic} at stamp {stamp} ns"
    data = np.asarray(obj.data, dtype=np.uint8)
    try:
        kind = image_kind(msg.msgtype, obj, msg.topic)
        if isinstance(rect, str):
            raise CalibrationMismatchError(f"{where}: its CameraInfo is unusable: {rect}")
        decoded = rect.decode_message(kind, obj, where)
    except UnsupportedImageError as err:
        _unsupported(msg, str(err), st)
        raise RowReject(Reason.UNSUPPORTED_IMAGE, msg.file, str(err)) from err
    except (CorruptImageError, CalibrationMismatchError) as err:
        reason = Reason.CORRUPT_JPEG if isinstance(err, CorruptImageError) else (
            Reason.CALIBRATION_MISMATCH)  # fmt: skip
        raise RowReject(reason, msg.file, str(err)) from err
    row = {"camera": camera, "frame": -1, "stamp_ns": stamp, **message_where(msg),
           "jpeg_bytes": int(data.size)}  # fmt: skip
    emit = emit_image(camera, stamp, rect.remap(decoded), rect.K_out, st.sink, st.frames)
    if not drift_on(st.checks) or st.trusted(msg) or kind != "jpeg":
        return Indexed(row, msg.file, emit=emit)  # no drift check: it looks for JPEG DC damage
    return Indexed(row, msg.file, cells=jpeg_cells(data, decoded, stamp, rect.reduction),
                   emit=emit)  # fmt: skip


def _unsupported(msg: Message, detail: str, st: StreamState) -> None:
    """One warning per topic of images of an encoding m3gd does not read (each message is an
    `unsupported_image` reject, not damage)."""
    if msg.topic not in st.unsupported:
        st.unsupported.add(msg.topic)
        st.notes.append(f"{msg.file}: {detail}; its images are not ingested (counted as "
                        "unsupported_image, not as damage)")  # fmt: skip
