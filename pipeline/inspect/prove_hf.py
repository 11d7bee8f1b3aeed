"""What inspect's proof reads from a mission in the Hugging Face layout (`data/` Zarr store,
`images/<group>/NNNNNN.jpeg`), as `prove_read` reads bags.

The layout has no log times: a view's time is a row `timestamp` (int64 ns). Views are spread
over the reference LiDAR group's stamps (`prove_read.view_times`); per view each LiDAR group's
first scan at or after it (ingest's `ScanReader`: the valid points, every point at the scan's
stamp: the release has no per-point time), each camera group's first image at or after the
sweep's stamp plus `LAG_NS` less `IMAGE_LEAD_NS`, rectified through the group's `camera_info`
attribute to at most `WIDTH_PX` wide. Poses: every odometry group's rows (`pose_pos`,
`pose_orien` x, y, z, w) within `WINDOW_NS` of a view; the static tree from every `tf`
attribute, read in ingest's default direction (`ingest.hf.tf_direction`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np

from packets.poses import make_T, quat_to_rot
from pipeline.ingest.calib.camera import Rectifier
from pipeline.ingest.calib.tf_tree import TfTree
from pipeline.ingest.sources.hf.calib import hf_camera, tf_tree
from pipeline.ingest.sources.hf.points import BadScan, ScanReader, decode_scan
from pipeline.ingest.sources.hf.store import DECODE_ERRORS, HfStore
from pipeline.inspect.model import Inspection
from pipeline.inspect.prove_read import (
    IMAGE_LEAD_NS,
    LAG_NS,
    WINDOW_NS,
    ImageView,
    ProofData,
    SweepView,
    image_view,
    small_rectifier,
    sweep_view,
    view_times,
)
from schemas.config import HfConfig
from schemas.errors import DataError

I64 = Any
T = TypeVar("T")


class Usable(NamedTuple):
    """A group's rows whose stamp was read (`HfStore.stamps`' ok), in stamp order: row numbers
    (n,) and their stamps (n,) int64 ns. Ingest rejects the other rows, so no view uses one."""

    rows: I64
    stamps: I64


def usable(store: HfStore, group: str) -> Usable:
    """The group's `Usable` rows: unreadable stamp chunks (read as 0) left out, the rest
    sorted by stamp (stable, so equal stamps keep their row order)."""
    ns, ok = store.stamps(group)
    rows = np.flatnonzero(ok)
    order = np.argsort(ns[rows], kind="stable")
    return Usable(rows[order], ns[rows][order])


def _row_at(rows: Usable, at_ns: int) -> tuple[int, int] | None:
    """(row, stamp ns) of the first usable row stamped at or after `at_ns`, or None."""
    i = int(np.searchsorted(rows.stamps, at_ns, side="left"))
    return (int(rows.rows[i]), int(rows.stamps[i])) if i < rows.stamps.size else None


def _static(store: HfStore, problems: list[str]) -> TfTree:
    """Every group's `tf` attribute as one static tree (ingest's default direction)."""
    entries: dict[str, object] = {}
    for group in store.groups:
        tf = store.attrs(group).get("tf")
        if isinstance(tf, dict):
            entries.update(tf)
    tree, rejects = tf_tree(entries, HfConfig().tf_direction, "tf attributes")
    problems += [r.detail for r in rejects]
    return tree


def _sweep(store: HfStore, reader: ScanReader, stamps: Usable, at_ns: int,
           data: ProofData) -> SweepView | None:  # fmt: skip
    """The group's first scan at or after `at_ns`, decoded, its edges."""
    found = _row_at(stamps, at_ns)
    if found is None:
        return None
    row, stamp = found
    got = reader.scan(row)
    if isinstance(got, BadScan):
        raise DataError(got.detail)
    return sweep_view(reader.group, stamp, stamp, decode_scan(got[0], got[1], stamp), data)


def _rectifier(store: HfStore, group: str) -> Rectifier:
    """The group's rectifier from its `camera_info` attribute; ValueError when it has none."""
    try:
        cam = hf_camera(store, group, group, "")
    except TypeError as err:
        raise ValueError(f"{store.where(group)}: unusable camera_info: {err}") from err
    if cam is None:
        raise ValueError(f"{store.where(group)}: no camera_info attribute")
    return small_rectifier(cam)


def _image(store: HfStore, group: str, rect: Rectifier, stamps: Usable,
           at_ns: int) -> ImageView | None:  # fmt: skip
    """The group's first image at or after `at_ns`, rectified, grey."""
    found = _row_at(stamps, at_ns)
    if found is None:
        return None
    row, stamp = found
    path = store.image_path(group, row)
    where = f"{path.relative_to(store.mission_dir)} (row {row} of {store.where(group)})"
    try:
        raw = path.read_bytes()
    except FileNotFoundError as err:
        raise DataError(f"{where}: no such file") from err
    return image_view(stamp, rect.apply(raw, where), rect)


def _odometry(store: HfStore, group: str, times: list[int]) -> list[tuple[int, np.ndarray]]:
    """(stamp ns, T_odom_base (4, 4)) of the group's rows within WINDOW_NS of `times`."""
    stamps = store.stamps(group)[0]
    good = usable(store, group)
    pos_a, quat_a = store.array(group, "pose_pos"), store.array(group, "pose_orien")
    rows: set[int] = set()
    for t in times:
        lo, hi = np.searchsorted(good.stamps, [t - WINDOW_NS, t + WINDOW_NS + 1])
        rows.update(int(r) for r in good.rows[int(lo):int(hi)])
    out = []
    for lo, hi in _runs(sorted(rows)):
        pos = np.asarray(pos_a[lo:hi], np.float64).reshape(hi - lo, -1)
        quat = np.asarray(quat_a[lo:hi], np.float64).reshape(hi - lo, -1)
        for k in range(hi - lo):
            q = quat[k]
            if np.isfinite(pos[k]).all() and np.isfinite(q).all() and np.linalg.norm(q) > 1e-9:
                out.append((int(stamps[lo + k]), make_T(quat_to_rot(q / np.linalg.norm(q)),
                                                        pos[k, :3])))  # fmt: skip
    return out


def _runs(rows: list[int]) -> list[tuple[int, int]]:
    """Consecutive row numbers as [start, stop) runs."""
    out: list[tuple[int, int]] = []
    for r in rows:
        if out and r == out[-1][1]:
            out[-1] = (out[-1][0], r + 1)
        else:
            out.append((r, r + 1))
    return out


def hf_proof_data(path: Path, ins: Inspection, lidars: list[str]) -> ProofData:
    """The proof's views of an HF mission inspected as `ins` (module docstring); what cannot
    be read is one line of `ProofData.problems`."""
    store = HfStore.open(path)
    problems: list[str] = []
    data = ProofData(path, _static(store, problems), problems=problems)
    if not lidars or not store.has(lidars[0]):
        data.problems.append("no reference LiDAR group to spread the views over")
        return data
    ref_stamps = usable(store, lidars[0]).stamps
    times = view_times(int(ref_stamps[0]), int(ref_stamps[-1])) if ref_stamps.size else []
    if not times:
        data.problems.append("the reference LiDAR's recording is too short for views")
        return data
    for group in lidars:
        try:
            reader, stamps = ScanReader(store, group), usable(store, group)
        except (DataError, *DECODE_ERRORS) as err:
            data.problems.append(f"LiDAR {group}: {err}")
            continue
        data.sweeps[group] = [_guard(data, _sweep, store, reader, stamps, t, data)
                              for t in times]  # fmt: skip
    ref = data.sweeps.get(lidars[0], [])
    for cam in ins.cameras:
        try:
            rect, stamps = _rectifier(store, cam.image_topic), usable(store, cam.image_topic)
        except (DataError, ValueError, *DECODE_ERRORS) as err:
            data.problems.append(f"camera {cam.image_topic}: {err}")
            continue
        data.images[cam.image_topic] = [
            None if s is None else _guard(data, _image, store, cam.image_topic, rect, stamps,
                                          s.stamp_ns + LAG_NS - IMAGE_LEAD_NS)
            for s in ref]  # fmt: skip
    for group, _, _ in ins.odometry:
        try:
            data.odometry[group] = _odometry(store, group, times)
        except (DataError, *DECODE_ERRORS) as err:
            data.problems.append(f"odometry {group}: {err}")
    return data


def _guard(data: ProofData, read: Callable[..., T], *args: Any) -> T | None:
    """`read(*args)`, or None with the problem noted (a damaged row leaves its view out)."""
    try:
        return read(*args)
    except (DataError, *DECODE_ERRORS) as err:
        data.problems.append(str(err))
        return None
