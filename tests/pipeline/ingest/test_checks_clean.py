"""The plausibility checks reject nothing of clean recordings (no false rejects).

Synthetic recordings with a walking and a fast, turning robot (speed swings to 3.6 m/s, yaw up
to 1.5 rad/s): every image, sweep and pose read is kept, the rejects table is empty. The short
version (2 recordings) is in the default suite; all four scenes in both motions are slow.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.ingest.recording import ingest_recording
from pipeline.synth.api import synthesize
from schemas.config import IngestConfig, SceneName, SynthConfig
from schemas.recording_index import ACCOUNTING, REJECTS, read_index_table, table_path

FAST = {"speed_mps": 2.0, "speed_variation": 0.8, "yaw_rate_max_rps": 1.5, "yaw_period_s": 2.0}


def _ingest_clean(root: Path, scene: SceneName, fast: bool, size: tuple[int, int],
                  points: int) -> None:  # fmt: skip
    """Synthesize one recording, ingest it, assert nothing was rejected and all was kept."""
    name = f"{scene}{int(fast)}"
    motion = FAST if fast else {}
    cfg = SynthConfig(seed=3, seconds=2.0, image_width=size[1], image_height=size[0],
                      points_per_sweep=points, depth_maps=False, **motion)  # fmt: skip
    synthesize(root, cfg, scene, name)
    res = ingest_recording(root / name, root / "out", IngestConfig(out_height=112, out_width=168))
    rejects = read_index_table(table_path(res.index_dir, "rejects"), REJECTS).to_pylist()
    assert rejects == [], [(r["reason"], r["detail"]) for r in rejects[:3]]
    acc = read_index_table(table_path(res.index_dir, "accounting"), ACCOUNTING).to_pylist()
    assert acc and all(a["kept"] == a["read"] for a in acc)
    assert res.sweeps > 0 and res.odometry > 0 and min(res.images.values()) > 0


@pytest.mark.parametrize(("scene", "fast"), [("corridor", True), ("plaza", False)])
def test_clean_recording_no_rejects(tmp_path: Path, scene: SceneName, fast: bool) -> None:
    _ingest_clean(tmp_path, scene, fast, (160, 240), 4096)


@pytest.mark.slow
@pytest.mark.parametrize("fast", [False, True])
@pytest.mark.parametrize("scene", ["corridor", "warehouse", "forest", "plaza"])
def test_clean_recording_no_rejects_all_scenes(tmp_path: Path, scene: SceneName,
                                               fast: bool) -> None:  # fmt: skip
    _ingest_clean(tmp_path, scene, fast, (320, 480), 16384)
