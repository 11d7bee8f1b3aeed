"""Static calibration of a Hugging Face mission: the `tf` attribute tree and camera_info attributes.

`tf` direction (decision, tested on a rig with a known answer in
tests/pipeline/ingest/sources/hf/test_tf_direction.py): an
entry `{translation, rotation, base_frame_id}`
of frame c with base p is read as T_c_p, the map of *parent* coordinates into the child frame.
That is the reading under which the maintainers' helper (which returns
M_parent . inv(M_child) as "tf_echo parent child") is self-consistent, and under which the
release's hdr_front rotation puts the optical axis along box_base +x; it is the inverse of the
ROS edge. `ingest.hf.tf_direction: parent_from_child` selects the ROS reading instead.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from packets.poses import F64, invert_T, make_T, quat_to_rot
from pipeline.ingest.calib.camera import RawCamera, build_rectifier, camera_from_info
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.checks.rejects import Reject
from pipeline.ingest.errors import MissingTransformError
from pipeline.ingest.sources.hf.store import HfStore
from pipeline.ingest.sources.static import StaticCalib
from schemas.config import IngestConfig
from schemas.errors import DataError
from schemas.recording_index import Reason


def entry_T(entry: dict[str, Any], where: str) -> F64:
    """(4, 4) transform of one `tf` entry (rotation keyed w, x, y, z); DataError if unusable."""
    try:
        t, q = entry["translation"], entry["rotation"]
        quat = np.array([q["x"], q["y"], q["z"], q["w"]], dtype=np.float64)
        pos = np.array([t["x"], t["y"], t["z"]], dtype=np.float64)
    except (KeyError, TypeError) as err:
        raise DataError(f"{where}: transform entry lacks {err}: {entry}") from err
    if not (np.isfinite(quat).all() and np.isfinite(pos).all()) or np.linalg.norm(quat) < 1e-9:
        raise DataError(f"{where}: non-finite or zero transform {entry}")
    return make_T(quat_to_rot(quat / np.linalg.norm(quat)), pos)


def tf_tree(tf: dict[str, Any], direction: str, where: str) -> tuple[TfTree, list[Reject]]:
    """The static tree from a `tf` attribute {child: entry}, read in `direction`; bad entries
    become rejects naming the entry."""
    tree, rejects = TfTree(), []
    for child, entry in sorted(tf.items()):
        try:
            T = entry_T(entry, f"{where} entry {child!r}")
            parent = str(entry["base_frame_id"])
        except (ValueError, KeyError) as err:
            rejects.append(Reject(where, "tf", 0, Reason.UNDECODABLE_MESSAGE, str(err)))
            continue
        tree.add(parent, child, invert_T(T) if direction == "child_from_parent" else T)
    return tree, rejects


def read_hf_static(store: HfStore, cfg: IngestConfig) -> StaticCalib:
    """TF tree from the `tf` group and CameraInfo + rectifier per configured camera."""
    hf = cfg.hf
    group = store.group(hf.tf_group, "static transform")
    where = store.where(hf.tf_group)
    tf = dict(group.attrs).get("tf")
    if not isinstance(tf, dict) or not tf:
        raise DataError(f"{where}: attribute 'tf' is missing or empty: no calibration")
    calib = StaticCalib()
    calib.tf, calib.rejects = tf_tree(tf, hf.tf_direction, where)
    for camera in cfg.cameras:
        name = hf.group(camera)
        if store.has(name):
            _camera(store, cfg, camera, name, calib)
    for camera in cfg.cameras:
        if camera not in calib.cameras:
            _skipped_chain(cfg, camera, where, calib)
    return calib


def hf_camera(store: HfStore, group: str, camera: str, frame: str) -> RawCamera | None:
    """The camera model of a group's `camera_info` attribute, in the group's `frame_id` (else
    `frame`); None when the group has no such attribute, ValueError or TypeError when it is
    unusable."""
    attrs = store.attrs(group)
    info = attrs.get("camera_info")
    if not isinstance(info, dict):
        return None
    msg = SimpleNamespace(distortion_model=info.get("distortion_model", ""), K=info.get("K"),
                          D=info.get("D"), width=info.get("width"), height=info.get("height"),
                          header=SimpleNamespace(frame_id=str(attrs.get("frame_id") or frame)))
    return camera_from_info(camera, msg, f"{store.where(group)} camera_info")


def _camera(store: HfStore, cfg: IngestConfig, camera: str, group: str,
            calib: StaticCalib) -> None:  # fmt: skip
    """One camera's model and rectifier from its `camera_info` attribute, or a reject."""
    where = store.where(group)
    try:
        cam = hf_camera(store, group, camera, cfg.topics.frame_of(camera))
    except (ValueError, TypeError) as err:
        calib.rejects.append(Reject(where, group, 0, Reason.MISSING_CAMERA_INFO,
                                    f"unusable camera_info: {err}"))  # fmt: skip
        return
    if cam is None:
        calib.rejects.append(Reject(where, group, 0, Reason.MISSING_CAMERA_INFO,
                                    f"{where} has no camera_info attribute; images of camera "
                                    f"'{camera}' are not ingested"))  # fmt: skip
        return
    calib.cameras[camera] = cam
    calib.rectifiers[camera] = build_rectifier(
        cam, (cfg.out_height, cfg.out_width), balance=cfg.rectify_balance,
        reduced=cfg.reduced_decode,
    )  # fmt: skip


def _skipped_chain(cfg: IngestConfig, camera: str, where: str, calib: StaticCalib) -> None:
    """Record (not raise) a missing TF chain of a camera skipped for another reason."""
    try:
        calib.tf.lookup(cfg.topics.base_frame, cfg.topics.frame_of(camera))
    except MissingTransformError as err:
        calib.rejects.append(Reject(where, "tf", 0, Reason.MISSING_TF_EDGE, str(err)))
