"""Images of the streaming pass: decode and rectify one image message (JPEG, PNG or raw,
following its camera's CameraInfo), hold it for the drift check against its neighbouring
frames, then hand it to the image sink and index it, or reject it with a named reason."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from packets.poses import F64
from pipeline.ingest.checks.check_fit import Release
from pipeline.ingest.checks.image_drift import IMAGE_CHECKS, Judged, jpeg_cells
from pipeline.ingest.checks.rejects import Reject
from pipeline.ingest.core.stream_state import (
    CameraImage,
    HeldImage,
    StreamState,
    Writers,
)
from pipeline.ingest.core.sweep_stream import message_where
from pipeline.ingest.errors import (
    CalibrationMismatchError,
    CorruptImageError,
    UnsupportedImageError,
)
from pipeline.ingest.sources.bags import Message
from pipeline.ingest.sources.image_decode import image_kind
from schemas.recording_index import Reason


def image_message(msg: Message, obj: Any, stamp: int, camera: str, st: StreamState,
           out: Writers) -> bool | None:  # fmt: skip
    """Rectify one CompressedImage, hand it to the sink and index it; False if rejected.

    With the image checks on it is held (None: decided later) until the camera's next image
    is decoded, then judged against it and the last accepted image (`image_drift`).
    """
    rect = st.rectifier_at(camera, stamp)
    if rect is None:  # no camera_info: reported once by read_static
        return False
    where = f"{msg.file}: {msg.topic} at stamp {stamp} ns"
    data = np.asarray(obj.data, dtype=np.uint8)
    try:
        kind = image_kind(msg.msgtype, obj, msg.topic)
        if isinstance(rect, str):
            raise CalibrationMismatchError(f"{where}: its CameraInfo is unusable: {rect}")
        decoded = rect.decode_message(kind, obj, where)
    except UnsupportedImageError as err:
        _unsupported(msg, stamp, str(err), st, out)
        return False
    except (CorruptImageError, CalibrationMismatchError) as err:
        reason = Reason.CORRUPT_JPEG if isinstance(err, CorruptImageError) else (
            Reason.CALIBRATION_MISMATCH)  # fmt: skip
        out.rejects.add(Reject(msg.file, msg.topic, stamp, reason, str(err)))
        return False
    image = rect.remap(decoded)
    c = st.checks
    if not (c.enabled and (c.image_step_z or c.image_blip_levels)):
        _emit_image(msg, stamp, camera, image, int(data.size), rect.K_out, st, out)
        return True
    hold = st.images()
    if st.trusted(msg) or kind != "jpeg":  # no drift check (it looks for JPEG DC damage):
        _judged(hold.pop(camera), st, out)  # handed on in order, after any image still held
        for rel in st.fit(msg.topic, IMAGE_CHECKS).push(
                HeldImage(msg, stamp, image, int(data.size), None, rect.K_out), {},
                trusted=True):  # fmt: skip
            release_image(rel, st, out)
        return None
    cells = jpeg_cells(data, decoded, stamp, rect.reduction)
    _judged(hold.push(camera, HeldImage(msg, stamp, image, int(data.size), cells, rect.K_out),
                      cells), st, out)  # fmt: skip
    return None


def _unsupported(msg: Message, stamp: int, detail: str, st: StreamState, out: Writers) -> None:
    """Refuse an image of an encoding m3gd does not read: a reject row per message (counted
    as `unsupported_image`, not damage) and one warning per topic."""
    if msg.topic not in st.unsupported:
        st.unsupported.add(msg.topic)
        st.notes.append(f"{msg.file}: {detail}; its images are not ingested (counted as "
                        "unsupported_image, not as damage)")  # fmt: skip
    out.rejects.add(Reject(msg.file, msg.topic, stamp, Reason.UNSUPPORTED_IMAGE, detail))


def _judged(judged: list[Judged], st: StreamState, out: Writers) -> None:
    """Held images judged by the drift check (`image_drift.DriftHold`), to their topic's
    checks: emitted or rejected as these let them go."""
    for held, problem in judged:
        for rel in st.fit(held.msg.topic, IMAGE_CHECKS).push(held, {"image_drift": problem}):
            release_image(rel, st, out)


def release_image(rel: Release, st: StreamState, out: Writers) -> None:
    """Emit an image let go by its topic's checks, or reject it."""
    held: HeldImage = rel.item
    msg = held.msg
    if rel.rejected_by is not None:
        out.rejects.add(Reject(msg.file, msg.topic, held.stamp_ns, Reason.CORRUPT_JPEG,
                               rel.rejected_by[1]))  # fmt: skip
        return
    camera = st.image_topics[msg.topic]
    _emit_image(msg, held.stamp_ns, camera, held.image, held.jpeg_bytes, held.K_out, st, out)
    out.tally.kept[(msg.file, msg.topic)] += 1


def flush_images(st: StreamState, out: Writers) -> None:
    """Judge every held image against the last accepted one (the end of a bag)."""
    _judged(st.images().flush(), st, out)


def _emit_image(msg: Message, stamp: int, camera: str, image: npt.NDArray[np.uint8],
                jpeg_bytes: int, K_out: F64, st: StreamState, out: Writers) -> None:  # fmt: skip
    """Number an accepted image, hand it to the sink (with the intrinsics `K_out` of its own
    calibration) and index it."""
    frame = st.frames.get(camera, 0)
    st.frames[camera] = frame + 1
    if st.sink is not None:
        st.sink(CameraImage(camera, frame, stamp, image, K_out))
    row = {"camera": camera, "frame": frame, "stamp_ns": stamp, **message_where(msg),
           "jpeg_bytes": jpeg_bytes}  # fmt: skip
    out.images.append(row)
