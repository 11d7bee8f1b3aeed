"""The run's recordings: the mission folders a configuration names, and their names.

Configured missions (`ingest.recordings`) or, when none is configured, the synthesized ones
(`synth_<scene>_s<seed>` under the output's `recordings/`). Pure configuration to paths: the
run engine, the stages and the analysis all look missions up here.
"""

from __future__ import annotations

from pathlib import Path

from schemas.config import M3GDConfig
from schemas.errors import DataError, MissingDataError


def recordings(cfg: M3GDConfig) -> list[Path]:
    """Mission folders of this run: configured ones, or the synthesized ones."""
    if cfg.ingest.recordings:
        return [Path(p) for p in cfg.ingest.recordings]
    base = cfg.layout.recordings
    return [base / synth_mission_name(scene, cfg.synth.seed) for scene in cfg.synth.scenes]


def synth_mission_name(scene: str, seed: int) -> str:
    """Name of a synthesized mission folder."""
    return f"synth_{scene}_s{seed}"


def synth_scene_of(cfg: M3GDConfig, mission: str) -> str:
    """The configured scene whose synthesized mission is named `mission`."""
    for scene in cfg.synth.scenes:
        if synth_mission_name(scene, cfg.synth.seed) == mission:
            return scene
    raise DataError(f"{mission}: not the mission of any scene in synth.scenes {cfg.synth.scenes}")


def recording_names(cfg: M3GDConfig) -> list[str]:
    """Recording names (mission folder names) in a stable order."""
    return [p.name for p in recordings(cfg)]


def mission_of(cfg: M3GDConfig, recording: str) -> Path:
    """Mission folder of a recording name."""
    for path in recordings(cfg):
        if path.name == recording:
            return path
    raise MissingDataError(f"recording {recording!r} is not part of this run "
                           f"(its recordings: {[p.name for p in recordings(cfg)]})")
