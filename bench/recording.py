"""A synthesized, ingested and widely selected recording with its sweeps and pose chain: the
subject of the trade-table bench and of the clock-offset estimate."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from packets.poses import invert_T, lidar_to_camera
from schemas.config import M3GDConfig

F64 = npt.NDArray[np.float64]


@dataclass
class Recording:
    """A synthesized, ingested and widely selected recording, ready for the knobs."""

    cfg: M3GDConfig
    name: str
    mission: Path
    index: Path


def prepare(work: Path, scene: str, synth: dict[str, Any], seed: int = 0) -> Recording:
    """Synthesize one mission of `scene`, ingest it, select with a 10 s bound (all views kept)."""
    from pipeline.ingest.recording import ingest_recording
    from pipeline.select.views import select_views
    from pipeline.synth.api import synthesize

    base = {"scenes": [scene], "seed": seed, **synth}
    cfg = M3GDConfig.model_validate({
        "output_dir": str(work / "out"), "synth": base,
        "select": {"max_abs_dt_s": 10.0},
        "ingest": {"recordings": [str(work / "rec" / f"{scene}-{seed}")],
                   "cameras": synth.get("cameras", ["front", "left", "right"])}})
    res = synthesize(work / "rec", cfg.synth, scene, f"{scene}-{seed}")
    ing = ingest_recording(res.mission_dir, cfg.output_dir, cfg.ingest)
    select_views(ing.index_dir, cfg.select, cfg.ingest)
    return Recording(cfg, res.mission_dir.name, res.mission_dir, ing.index_dir)


class SweepStore:
    """Decoded sweeps of a recording by index (all kept: a few seconds of recording)."""

    def __init__(self, rec: Recording) -> None:
        """Read the recording's sweep index."""
        from schemas.recording_index import SWEEPS, read_index_table, table_path

        self.rec = rec
        rows = read_index_table(table_path(rec.index, "sweeps"), SWEEPS).to_pylist()
        self.rows = {r["sweep"]: r for r in rows}
        self._xyz: dict[int, npt.NDArray[np.float32]] = {}

    def xyz(self, sweep: int) -> npt.NDArray[np.float32]:
        """(N, 3) float32 points of a sweep (finite ones only)."""
        from pipeline.ingest.sources.sweep_reader import load_sweep

        if sweep not in self._xyz:
            pts = load_sweep(self.rec.mission, self.rows[sweep]).xyz
            self._xyz[sweep] = pts[np.isfinite(pts).all(axis=1)]
        return self._xyz[sweep]


@dataclass(frozen=True)
class Chain:
    """Static calibration and odometry of a recording: T_cam_lidar with or without the chain."""

    T_base: dict[str, F64]
    odo: Any

    @classmethod
    def load(cls, rec: Recording) -> Chain:
        """Calibration rows and odometry from the recording's index."""
        from pipeline.select.views import load_odometry
        from schemas.recording_index import CALIBRATION, read_index_table, table_path

        rows = read_index_table(table_path(rec.index, "calibration"), CALIBRATION).to_pylist()
        return cls({r["sensor"]: np.reshape(r["T_base_sensor"], (4, 4)) for r in rows},
                   load_odometry(rec.index))

    def static(self, camera: str) -> F64:
        """T_cam_lidar = T_cam_base T_base_lidar (no odometry: the robot assumed still)."""
        out: F64 = invert_T(self.T_base[camera]) @ self.T_base["lidar"]
        return out

    def chain(self, camera: str, image_ns: int, sweep_ns: int) -> F64 | None:
        """T_cam_lidar through odometry at both stamps (None outside the odometry)."""
        T, ok = self.odo.at(np.array([image_ns, sweep_ns], np.int64), 10**9)
        if not bool(ok.all()):
            return None
        out: F64 = lidar_to_camera(self.T_base[camera], T[:1], T[1:], self.T_base["lidar"])[0]
        return out
