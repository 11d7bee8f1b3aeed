"""Clips stage: the segment split of a one-recording cache (hand-built), and what it says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import zarr

from pipeline.stages.clips import _camera_clips, split_note
from schemas.config import ClipsConfig, M3GDConfig
from store.cache_store import open_root
from tests.model.cache_fixture import N, build_cache


def _cfg(out: Path, split: str = "auto") -> M3GDConfig:
    return M3GDConfig(output_dir=out, clips=ClipsConfig(views=4, gap_min=1, gap_max=2,
                                                        eval_fraction=0.25, split=split))


def test_one_recording_gets_train_and_eval_clips_apart_by_the_gap(tmp_path: Path) -> None:
    def all_valid(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
        arrays["valid"][:] = True

    build_cache(tmp_path, ("only",), ("front", "left"), fill=all_valid)
    cfg = _cfg(tmp_path)
    for cam in ("front", "left"):
        group = open_root(tmp_path / "cache.zarr")[f"only/{cam}"]
        assert isinstance(group, zarr.Group)
        rows = _camera_clips(group, "segment", 3, cfg, seed=0)
        train = [f for r in rows if r["split"] == "train" for f in r["frames"]]  # type: ignore[attr-defined]
        held = [r for r in rows if r["split"] == "eval"]
        assert train and held and len(held) <= 3
        first_eval = N - round(0.25 * N)  # 18 of 24 frames
        assert max(train) < first_eval - 6  # the gap: (views - 1) * gap_max frames
        assert all(f >= first_eval for r in held for f in r["frames"])  # type: ignore[attr-defined]
        assert all(sum(not t for t in r["is_target"]) == 2 for r in held)  # type: ignore[attr-defined]


def test_the_segment_split_says_why_and_where_the_gap_is(tmp_path: Path) -> None:
    auto = split_note("segment", _cfg(tmp_path), 1)
    assert auto is not None and "1 recording, too few to hold one out" in auto
    assert "last 25%" in auto and "more than 6 before it" in auto
    chosen = split_note("segment", _cfg(tmp_path, "segment"), 3)
    assert chosen is not None and "(clips.split: segment)" in chosen
    assert split_note("recording", _cfg(tmp_path), 3) is None
