"""Estimate an unknown camera-LiDAR clock offset of a recording (the pure estimator:
`bench.support.offset_search`), for the trade-table bench, where it is scored against the offset
synth injected. This module reads the images, sweeps and pose chain."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from bench.recording import Chain, Recording
from bench.support.offset_search import CANDIDATES_S, estimate, view_scores
from pipeline.ingest.calib.camera import RawCamera, build_rectifier
from pipeline.ingest.sources.bags import BagFile
from pipeline.ingest.sources.sweep_reader import load_sweep
from schemas.recording_index import (
    CALIBRATION,
    IMAGES,
    SELECTION,
    SWEEPS,
    read_index_table,
    table_path,
)

F64 = npt.NDArray[np.float64]
BLUR_SIGMA_PX = 2.0


def _gradients(rec: Recording, camera: str, frames: list[int]) -> dict[int, F64]:
    """Blurred image-gradient magnitude (H, W) of the rectified images of `frames`."""
    cal = {r["sensor"]: r for r in read_index_table(
        table_path(rec.index, "calibration"), CALIBRATION).to_pylist()}[camera]
    cam = RawCamera(camera, cal["frame_id"], cal["width"], cal["height"], cal["model"],
                    np.reshape(cal["K"], (3, 3)), np.asarray(cal["D"], np.float64))
    rect = build_rectifier(cam, (rec.cfg.ingest.out_height, rec.cfg.ingest.out_width))
    rows = [r for r in read_index_table(table_path(rec.index, "images"), IMAGES).to_pylist()
            if r["camera"] == camera and r["frame"] in set(frames)]
    want = {(r["file"], r["ordinal"]): r["frame"] for r in rows}
    out: dict[int, F64] = {}
    for file in sorted({r["file"] for r in rows}):
        bag = BagFile(rec.mission / file, rec.mission)
        for msg in bag.messages([rows[0]["topic"]]):
            frame = want.get((file, msg.ordinal))
            if frame is None:
                continue
            data = bytes(np.asarray(bag.deserialize(msg).data, dtype=np.uint8))
            gray = cv2.cvtColor(rect.apply(data, file), cv2.COLOR_RGB2GRAY).astype(np.float32)
            mag = np.hypot(cv2.Sobel(gray, cv2.CV_32F, 1, 0), cv2.Sobel(gray, cv2.CV_32F, 0, 1))
            out[frame] = cv2.GaussianBlur(mag, (0, 0), BLUR_SIGMA_PX).astype(np.float64)
        bag.close()
    return out


def estimate_offset(rec: Recording, camera: str = "front", views: int = 25) -> dict[str, Any]:
    """Offset (s) maximizing the LiDAR-edge / image-edge alignment over `views` accepted views.

    Each view keeps the sweep select chose; the image time is moved by every candidate.
    """
    sel = [r for r in read_index_table(table_path(rec.index, "selection"), SELECTION).to_pylist()
           if r["camera"] == camera and r["status"] == "ok"]
    sel = sel[:: max(1, len(sel) // views)]
    sweeps = {r["sweep"]: r for r in read_index_table(
        table_path(rec.index, "sweeps"), SWEEPS).to_pylist()}
    grads = _gradients(rec, camera, [r["frame"] for r in sel])
    chain = Chain.load(rec)
    hw = (rec.cfg.ingest.out_height, rec.cfg.ingest.out_width)
    total = np.zeros(CANDIDATES_S.size)
    for r in sel:
        sw = load_sweep(rec.mission, sweeps[r["sweep"]])
        transforms = [chain.chain(camera, r["stamp_ns"] - round(c * 1e9), r["sweep_stamp_ns"])
                      for c in CANDIDATES_S]
        total += view_scores(grads[r["frame"]], sw.xyz, sw.t_ns, np.reshape(r["K_out"], (3, 3)),
                             transforms, hw)
    return estimate(CANDIDATES_S, total, len(sel))
