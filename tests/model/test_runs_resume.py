"""A run records its validation recordings (`model.checkpoint.write_run`) and `--resume` holds
the same ones out without being told (`model.runs.start_training`)."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch

from model.checkpoint import RUN_FILE, read_run, write_run
from model.runs import TrainRequest, start_training
from schemas.config import M3GDConfig, parse_config
from schemas.errors import DataError
from schemas.layout import OutputLayout
from schemas.tables import CLIPS, write_table
from tests.model.cache_fixture import build_cache, stamp_encoders

RECORDINGS = ("r0", "r1", "r2", "r3")
CPU = torch.device("cpu")


def test_run_record_round_trip_and_refusal(tmp_path: Path) -> None:
    assert read_run(tmp_path) is None  # neither a record nor a checkpoint
    write_run(tmp_path, ["r2", "r0"])
    assert read_run(tmp_path) == ["r0", "r2"]
    (tmp_path / RUN_FILE).write_text(json.dumps({"format": "m3gd-train-run/9",
                                                 "val_recordings": []}))
    with pytest.raises(DataError, match=f"{RUN_FILE}: not a readable run record"):
        read_run(tmp_path)


def _cache(tmp_path: Path) -> M3GDConfig:
    """A config over a 4-recording, 1-camera fixture cache with its encoder identities."""
    build_cache(tmp_path / "out", RECORDINGS, ("front",))
    stamp_encoders(tmp_path / "out", RECORDINGS, ("front",))
    clips = OutputLayout(tmp_path / "out").clips  # r0-r2 train (the fixture trains r0 only)
    rows = pq.read_table(clips).to_pylist()
    for row in rows:
        row["split"] = "eval" if row["recording"] == "r3" else "train"
    write_table(pa.Table.from_pylist(rows, schema=CLIPS), CLIPS, clips)
    return parse_config({"output_dir": str(tmp_path / "out")})


def _recordings(setup: object) -> set[str]:
    return {c["recording"] for c in setup.stream.clips}  # type: ignore[attr-defined]


def test_resume_holds_out_the_recorded_validation_recordings(tmp_path: Path) -> None:
    cfg = _cache(tmp_path)
    ckpt = tmp_path / "ckpt"
    first = start_training(cfg, TrainRequest(mode="no_lidar", out=ckpt, val_recordings=1), CPU)
    assert len(first.val) == 1 and first.val[0] not in _recordings(first)
    first.trainer.save(ckpt)
    again = start_training(cfg, TrainRequest(out=ckpt, resume=True), CPU)  # option not repeated
    assert again.resumed and again.val == first.val
    assert _recordings(again) == _recordings(first)
    same = start_training(cfg, TrainRequest(out=ckpt, resume=True, val_recordings=1), CPU)
    assert same.val == first.val
    with pytest.raises(DataError, match="holding out 1 validation recording"):
        start_training(cfg, TrainRequest(out=ckpt, resume=True, val_recordings=2), CPU)


def test_a_run_without_validation_resumes_without_it(tmp_path: Path) -> None:
    cfg = _cache(tmp_path)
    ckpt = tmp_path / "ckpt"
    first = start_training(cfg, TrainRequest(mode="no_lidar", out=ckpt), CPU)
    assert first.val == [] and read_run(ckpt) == []
    first.trainer.save(ckpt)
    again = start_training(cfg, TrainRequest(out=ckpt, resume=True), CPU)
    assert again.val == [] and _recordings(again) == _recordings(first)
