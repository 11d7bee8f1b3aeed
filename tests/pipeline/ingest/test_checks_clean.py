"""The plausibility checks reject nothing of clean recordings (no false rejects).

Synthetic recordings with a walking and a fast, turning robot (speed swings to 3.6 m/s, yaw up
to 1.5 rad/s): every image, sweep and pose read is kept, the rejects table is empty. The short
version (2 recordings) is in the default suite; all four scenes in both motions are slow.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from pipeline.ingest.index.ingest_result import IngestResult
from pipeline.ingest.recording import ingest_recording
from pipeline.synth.api import synthesize
from schemas.config import IngestConfig, SceneName, SynthConfig
from schemas.recording_index import ACCOUNTING, REJECTS, read_index_table, table_path

FAST = {"speed_mps": 2.0, "speed_variation": 0.8, "yaw_rate_max_rps": 1.5, "yaw_period_s": 2.0}


Rows = list[dict[str, Any]]


def _ingest_clean(root: Path, scene: SceneName, fast: bool, size: tuple[int, int],
                  points: int) -> tuple[Rows, Rows, IngestResult]:  # fmt: skip
    """Synthesize one recording and ingest it; return its rejects rows, accounting rows and
    the ingest result."""
    name = f"{scene}{int(fast)}"
    motion = FAST if fast else {}
    cfg = SynthConfig(seed=3, seconds=2.0, image_width=size[1], image_height=size[0],
                      points_per_sweep=points, depth_maps=False, **motion)  # fmt: skip
    synthesize(root, cfg, scene, name)
    # every message judged: the synthetic chunks' checksums would let the checks skip them
    ingest = IngestConfig.model_validate({"out_height": 112, "out_width": 168,
                                          "checks": {"trust_checksums": False}})  # fmt: skip
    res = ingest_recording(root / name, root / "out", ingest)
    assert all(r["trusted"] == 0 for r in res.checks) and res.checks
    rejects = read_index_table(table_path(res.index_dir, "rejects"), REJECTS).to_pylist()
    acc = read_index_table(table_path(res.index_dir, "accounting"), ACCOUNTING).to_pylist()
    return rejects, acc, res


def _no_false_rejects(rejects: Rows, acc: Rows, res: IngestResult) -> bool:
    """Nothing rejected, every message read was kept, and every sensor delivered data."""
    return (not rejects and bool(acc) and all(a["kept"] == a["read"] for a in acc)
            and res.sweeps > 0 and res.odometry > 0 and min(res.images.values()) > 0)


@pytest.mark.parametrize(("scene", "fast"), [("corridor", True), ("plaza", False)])
def test_clean_recording_no_rejects(tmp_path: Path, scene: SceneName, fast: bool) -> None:
    rejects, acc, res = _ingest_clean(tmp_path, scene, fast, (160, 240), 4096)
    assert _no_false_rejects(rejects, acc, res), [(r["reason"], r["detail"]) for r in rejects[:3]]


@pytest.mark.slow
@pytest.mark.parametrize("fast", [False, True])
@pytest.mark.parametrize("scene", ["corridor", "warehouse", "forest", "plaza"])
def test_clean_recording_no_rejects_all_scenes(tmp_path: Path, scene: SceneName,
                                               fast: bool) -> None:  # fmt: skip
    rejects, acc, res = _ingest_clean(tmp_path, scene, fast, (320, 480), 16384)
    assert _no_false_rejects(rejects, acc, res), [(r["reason"], r["detail"]) for r in rejects[:3]]
