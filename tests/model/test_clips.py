"""Clip sampling: gaps, roles, split without overlap, determinism, hard flag geometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import zarr
from hypothesis import given, settings
from hypothesis import strategies as st

from model.clips import (
    max_baseline,
    sample_clips,
    segment_frames,
    segment_gap,
    split_mode,
    split_recordings,
)
from pipeline.stages.clips import _camera_clips
from schemas.config import ClipsConfig, M3GDConfig
from store.cache_store import open_root
from tests.model.cache_fixture import N, build_cache


def _line(n: int, step: float) -> np.ndarray:
    return np.stack([np.arange(n) * step, np.zeros(n), np.zeros(n)], axis=1)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 1000), gap_min=st.integers(2, 5), extra=st.integers(0, 15),
    split=st.sampled_from(["train", "eval"]),
)
def test_clip_rules(seed: int, gap_min: int, extra: int, split: str) -> None:
    gap_max = gap_min + extra
    valid = np.array([f for f in range(200) if f % 7 != 3], np.int64)
    clips = sample_clips(valid, _line(200, 0.1), 30, split, 4, gap_min, gap_max, seed)
    assert clips, "a long valid recording must give clips"
    seen = set()
    for clip in clips:
        gaps = np.diff(clip.frames)
        assert len(clip.frames) == len(clip.is_target) == 4
        assert np.all(gaps >= gap_min) and np.all(gaps <= gap_max)
        assert set(clip.frames) <= set(valid.tolist())
        n_src = clip.is_target.count(False)
        assert n_src == 2 if split == "eval" else 1 <= n_src <= 3
        assert clip.frames not in seen
        seen.add(clip.frames)


def test_deterministic_by_seed() -> None:
    valid = np.arange(100, dtype=np.int64)
    a = sample_clips(valid, _line(100, 0.5), 10, "train", 4, 1, 20, 3)
    b = sample_clips(valid, _line(100, 0.5), 10, "train", 4, 1, 20, 3)
    c = sample_clips(valid, _line(100, 0.5), 10, "train", 4, 1, 20, 4)
    assert a == b and a != c


def test_baseline_is_max_pairwise_distance() -> None:
    pos = np.array([[0, 0, 0], [3, 0, 0], [0, 4, 0]], float)
    assert max_baseline(pos) == 5.0
    clips = sample_clips(np.arange(50, dtype=np.int64), _line(50, 0.2), 5, "eval", 4, 1, 2, 0)
    for clip in clips:
        span = clip.frames[-1] - clip.frames[0]
        assert np.isclose(clip.max_baseline_m, 0.2 * span)


def test_split_has_no_overlap_and_both_sides() -> None:
    names = [f"rec{i}" for i in range(10)]
    split = split_recordings(names, 0.17, 0)
    assert set(split) == set(names)
    assert {"train", "eval"} == set(split.values())
    assert split == split_recordings(list(reversed(names)), 0.17, 0)
    assert "eval" in split_recordings(["a", "b"], 0.01, 1).values()
    assert set(split_recordings(["a", "b"], 0.0, 1).values()) == {"train"}


def test_fixed_gap_gives_evenly_spaced_frames() -> None:
    clips = sample_clips(np.arange(60, dtype=np.int64), _line(60, 0.1), 10, "train", 4, 3, 3, 0)
    assert clips and all(np.all(np.diff(c.frames) == 3) for c in clips)


def test_hard_flag_is_baseline_above_threshold(tmp_path: Path) -> None:
    """hard = max_baseline_m > hard_baseline_m; 0.25 m per frame puts spans on both sides."""
    def straight_line(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
        arrays["valid"][:] = True
        arrays["T_world_cam"][:, 0, 3] = np.arange(N) * 0.25  # exact in binary
    build_cache(tmp_path, ("r0",), ("front",), fill=straight_line)
    group = open_root(tmp_path / "cache.zarr")["r0/front"]
    assert isinstance(group, zarr.Group)
    for threshold in (0.8, 1.0, 1.3):  # spans of 3..6 frames: 0.75, 1.0, 1.25, 1.5 m
        cfg = M3GDConfig(output_dir=tmp_path, clips=ClipsConfig(
            views=4, gap_min=1, gap_max=2, hard_baseline_m=threshold))
        rows = _camera_clips(group, "eval", 40, cfg, seed=0)
        spans = set()
        for row in rows:
            frames = list(row["frames"])  # type: ignore[call-overload]
            span = frames[-1] - frames[0]
            spans.add(span)
            assert row["max_baseline_m"] == 0.25 * span
            assert row["hard"] == (0.25 * span > threshold), (threshold, row)
        assert spans == {3, 4, 5, 6}  # on both sides of every threshold; 1.0 m exactly at one
        assert {r["hard"] for r in rows} == {True, False}


def test_auto_split_is_by_segment_with_one_recording_only() -> None:
    assert split_mode("auto", 1, 0.17) == "segment"
    assert split_mode("auto", 2, 0.17) == "recording"
    assert split_mode("auto", 1, 0.0) == "recording"  # nothing to hold out
    assert split_mode("recording", 1, 0.17) == "recording"
    assert split_mode("segment", 5, 0.17) == "segment"


def test_segment_split_holds_out_the_end_behind_a_gap_of_one_clip_span() -> None:
    valid = np.array([f for f in range(100) if f != 90], np.int64)
    gap = segment_gap(4, 5)
    parts = segment_frames(valid, 100, 0.2, gap)
    assert gap == 15
    assert parts["eval"].tolist() == [f for f in range(80, 100) if f != 90]
    assert parts["train"].tolist() == list(range(65))  # 65..79: the gap, in neither split
    assert parts["eval"].min() - parts["train"].max() > gap
    assert segment_frames(valid, 100, 0.001, gap)["eval"].tolist() == [99]  # at least one


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 1000), fraction=st.floats(0.05, 0.5), gap_max=st.integers(1, 6))
def test_no_training_clip_comes_within_a_clip_span_of_an_eval_clip(
        seed: int, fraction: float, gap_max: int) -> None:
    valid = np.arange(200, dtype=np.int64)
    parts = segment_frames(valid, 200, fraction, segment_gap(4, gap_max))
    train = sample_clips(parts["train"], _line(200, 0.1), 50, "train", 4, 1, gap_max, seed)
    held = sample_clips(parts["eval"], _line(200, 0.1), 10, "eval", 4, 1, gap_max, seed)
    assert train and held
    last_train = max(c.frames[-1] for c in train)
    first_eval = min(c.frames[0] for c in held)
    assert first_eval - last_train > 3 * gap_max


def test_no_eval_clip_says_why_and_what_to_set(tmp_path: Path) -> None:
    import pyarrow as pa

    from model.clips import no_clip_message
    from schemas.tables import CLIPS, CLIPS_SPLIT_KEY, write_table

    row = {"clip_id": 0, "split": "train", "recording": "only", "camera": "front",
           "frames": [0, 1], "is_target": [False, True], "max_baseline_m": 0.1, "hard": False}
    path = tmp_path / "clips.parquet"
    write_table(pa.Table.from_pylist([row], schema=CLIPS), CLIPS, path)  # before clips.split
    text = no_clip_message(path, "eval")
    assert text.startswith(f"{path}: no 'eval' clip") and "\n" not in text
    assert "split by recording" in text and "1 recording" in text
    assert "clips.split: segment" in text
    segment = CLIPS.with_metadata({**(CLIPS.metadata or {}), CLIPS_SPLIT_KEY.encode(): b"segment"})
    write_table(pa.Table.from_pylist([row], schema=CLIPS), segment, path)
    assert "clips.eval_fraction" in no_clip_message(path, "eval")
