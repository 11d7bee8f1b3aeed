"""Images of the HF Zarr and KITTI-360 sources through the gated pass: HF's JPEGs get the bag
path's drift check (`image_drift`, `checks.image_drift`; a drifted image is refused with the
bag path's wording), KITTI-360's lossless PNGs do not (as the bag path skips PNG and raw);
clean recordings keep every view, and every record read is kept or rejected."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import simplejpeg

from pipeline.ingest.index.ingest_result import IngestResult
from pipeline.ingest.recording import ingest_recording
from pipeline.ingest.sources.kitti360 import Kitti360Source
from schemas.recording_index import (
    ACCOUNTING,
    CHECKS,
    IMAGES,
    REJECTS,
    read_index_table,
    table_path,
)
from tests.pipeline.ingest.sources import kitti360_kit as k360
from tests.pipeline.ingest.sources.hf import kit as hf

WORDING = re.compile(r"^colour component (Y|Cb|Cr) (steps from MCU row \d+ down against the "
                     r"\d neighbouring frame\(s\)|offset by [\d.]+ grey levels against both "
                     r"neighbouring frames) .*: damaged JPEG data decoded without an error$")
"""The bag path's reject detail of a drifted image (`image_checks.step_problem`,
`blip_problem`)."""
FRAME = 6


def drift_band(rgb: np.ndarray, level: int = 40) -> np.ndarray:
    """The image with every pixel from the middle row down offset by `level` in red and
    -`level` in blue (a chroma band, as a flipped DC bit decodes)."""
    out = rgb.astype(np.int16)
    out[rgb.shape[0] // 2 :] += np.array([level, 0, -level], dtype=np.int16)
    return np.clip(out, 0, 255).astype(np.uint8)


def _table(res: IngestResult, name: str, schema: Any) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = read_index_table(table_path(res.index_dir, name),
                                                  schema).to_pylist()  # fmt: skip
    return rows


def _all_accounted(res: IngestResult) -> None:
    """Every record read is kept (an index row) or rejected (a reject row)."""
    acc = _table(res, "accounting", ACCOUNTING)
    assert acc and res.unaccounted == {}
    assert all(r["read"] == r["kept"] + r["rejected"] for r in acc), acc


def _drift_rows(res: IngestResult) -> list[dict[str, Any]]:
    return [r for r in _table(res, "checks", CHECKS) if r["check"] == "image_drift"]


def _ingest_hf(root: Path, out: Path) -> IngestResult:
    return ingest_recording(root, out, hf.INGEST)


def _ingest_kitti(root: Path, out: Path) -> IngestResult:
    return Kitti360Source().ingest(root, out, k360.INGEST, None, "k")


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> dict[str, IngestResult]:
    out = tmp_path_factory.mktemp("clean")
    return {"hf": _ingest_hf(hf.mission(tmp_path_factory, "clean", "hf-zarr"), out / "h"),
            "kitti": _ingest_kitti(k360.kitti_root(tmp_path_factory), out / "k")}  # fmt: skip


@pytest.mark.parametrize("source", ["hf", "kitti"])
def test_clean_recordings_keep_every_view(clean: dict[str, IngestResult], source: str) -> None:
    res = clean[source]
    assert "corrupt_jpeg" not in res.rejects
    images = _table(res, "images", IMAGES)
    acc = {r["topic"]: r for r in _table(res, "accounting", ACCOUNTING)}
    cams = {r["topic"] for r in images}
    assert cams and all(acc[t]["kept"] == acc[t]["read"] for t in cams)
    drift = _drift_rows(res)  # the JPEG drift check on every JPEG camera, on no PNG one
    assert {r["topic"] for r in drift} == (cams if source == "hf" else set())
    assert all(r["state"] == "on" and r["rejected"] == 0 and r["messages"] > 0 for r in drift)
    _all_accounted(res)


def test_hf_drifted_image_is_refused_with_the_bag_wording(
        tmp_path_factory: pytest.TempPathFactory, tmp_path: Path,
        clean: dict[str, IngestResult]) -> None:  # fmt: skip
    rec = hf.copy_of(tmp_path_factory, "clean", tmp_path)
    path = rec / "images" / "hdr_front" / f"{FRAME:06d}.jpeg"
    data = path.read_bytes()
    sub = simplejpeg.decode_jpeg_header(data)[3]
    rgb = simplejpeg.decode_jpeg(data, "RGB")
    path.write_bytes(simplejpeg.encode_jpeg(drift_band(rgb), quality=95, colorspace="RGB",
                                            colorsubsampling=sub))  # fmt: skip
    res = _ingest_hf(rec, tmp_path / "out")
    assert res.rejects == {"corrupt_jpeg": 1}
    (r,) = _table(res, "rejects", REJECTS)
    assert r["file"] == f"images/hdr_front/{FRAME:06d}.jpeg" and r["topic"] == "hdr_front"
    assert WORDING.match(r["detail"]), r["detail"]
    assert res.images["front"] == clean["hf"].images["front"] - 1
    assert res.images == {**clean["hf"].images, "front": res.images["front"]}
    (front,) = [d for d in _drift_rows(res) if d["topic"] == "hdr_front"]
    assert front["rejected"] == 1 and front["state"] == "on"
    frames = [i["frame"] for i in _table(res, "images", IMAGES) if i["camera"] == "front"]
    assert frames == list(range(len(frames)))  # the kept images numbered without a hole
    _all_accounted(res)


def test_a_kitti360_png_is_not_judged_by_the_jpeg_drift_check(
        tmp_path_factory: pytest.TempPathFactory, tmp_path: Path,
        clean: dict[str, IngestResult]) -> None:  # fmt: skip
    """The drift check looks for the bands damaged JPEG data decodes to; a lossless PNG cannot
    carry them, so a band painted into one is the scene's, and the frame is kept (the bag path
    skips PNG and raw images alike)."""
    root = k360.copy_of(tmp_path_factory, tmp_path)
    path = root / "data_2d_raw" / k360.SEQ / "image_00" / "data_rect" / f"{FRAME:010d}.png"
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert cv2.imwrite(str(path), drift_band(bgr[..., ::-1])[..., ::-1])
    res = _ingest_kitti(root, tmp_path / "out")
    assert "corrupt_jpeg" not in res.rejects
    assert res.images == clean["kitti"].images
    _all_accounted(res)
