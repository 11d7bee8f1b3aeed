"""Clip sampling (pure): V views of one recording and camera, sources and targets.

A clip is V distinct frames in increasing order whose consecutive gaps lie in
[gap_min, gap_max] frames, all valid views. Training clips have 1-3 sources
(the rest targets); evaluation clips exactly 2 sources and 2 targets (V = 4).

The split is made before any clip is drawn (`split_mode`):
  recording  whole recordings go to eval (`split_recordings`): no recording is in both splits;
  segment    within each recording, the last `eval_fraction` of every camera's frames is the
             eval segment, and the `gap` frames before it (one clip span, (V - 1) * gap_max)
             belong to neither split (`segment_frames`): a training clip ends at least one clip
             span before the first eval frame, so the robot has moved on by as many frames as
             an eval clip spans. A recording that returns to a place it passed before can
             still show it in both splits: with two recordings or more, split by recording.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Clip:
    """One clip: frames (V,) in increasing order, is_target (V,), max camera baseline (m)."""

    frames: tuple[int, ...]
    is_target: tuple[bool, ...]
    max_baseline_m: float


def split_recordings(names: list[str], eval_fraction: float, seed: int) -> dict[str, str]:
    """Assign recordings to train or eval; one of each when >= 2 and eval_fraction > 0."""
    order = sorted(names)
    rng = np.random.default_rng(seed)
    perm = [order[i] for i in rng.permutation(len(order))]
    n_eval = round(eval_fraction * len(order))
    if len(order) >= 2 and eval_fraction > 0:
        n_eval = min(max(n_eval, 1), len(order) - 1)
    return {name: ("eval" if i < n_eval else "train") for i, name in enumerate(perm)}


SPLIT_MODES = ("recording", "segment")


def split_mode(setting: str, recordings: int, eval_fraction: float) -> str:
    """The split `clips.split` calls for: `setting` unless "auto", which is "recording" with
    two recordings or more (or no eval share) and "segment" with one."""
    if setting != "auto":
        return setting
    return "segment" if recordings < 2 and eval_fraction > 0 else "recording"


def segment_gap(views: int, gap_max: int) -> int:
    """Frames between the train and the eval segment of a recording: one clip span."""
    return (views - 1) * gap_max


def segment_frames(valid: NDArray[np.int64], n_frames: int, eval_fraction: float, gap: int
                   ) -> dict[str, NDArray[np.int64]]:
    """Split the valid frame numbers (sorted) of a recording-camera of `n_frames` frames in
    time: "eval" the frames from `n_frames - round(eval_fraction * n_frames)` on (at least one
    when eval_fraction > 0), "train" those more than `gap` frames before the first eval frame;
    the ones between are in neither."""
    n_eval = round(eval_fraction * n_frames)
    if eval_fraction > 0:
        n_eval = max(n_eval, 1)
    start = n_frames - n_eval
    return {"train": valid[valid < start - gap], "eval": valid[valid >= start]}


def max_baseline(positions: NDArray[np.float64]) -> float:
    """Largest pairwise distance (m) among camera centres (V, 3)."""
    diff = positions[:, None, :] - positions[None, :, :]
    return float(np.sqrt((diff**2).sum(-1)).max())


def _draw_frames(valid: NDArray[np.int64], views: int, gap_min: int, gap_max: int,
                 rng: np.random.Generator) -> tuple[int, ...] | None:
    """Frames of one clip from the sorted valid frame numbers, or None if no fit."""
    if len(valid) < views:
        return None
    valid_set = set(valid.tolist())
    for _ in range(20):
        frames = [int(rng.choice(valid))]
        for _ in range(views - 1):
            gap = int(rng.integers(gap_min, gap_max + 1))
            nxt = frames[-1] + gap
            if nxt not in valid_set:
                break
            frames.append(nxt)
        if len(frames) == views:
            return tuple(frames)
    return None


def _roles(views: int, n_sources: int, rng: np.random.Generator) -> tuple[bool, ...]:
    """Which positions are targets: `views - n_sources` random positions."""
    target = np.ones(views, bool)
    target[rng.choice(views, n_sources, replace=False)] = False
    return tuple(bool(t) for t in target)


def sample_clips(valid_frames: NDArray[np.int64], positions: NDArray[np.float64], count: int,
                 split: str, views: int, gap_min: int, gap_max: int, seed: int) -> list[Clip]:
    """Up to `count` distinct clips of one recording and camera.

    valid_frames: (M,) sorted frame numbers of valid views; positions: (N, 3) camera
    centres in the world frame (metres) indexed by frame number.
    """
    rng = np.random.default_rng(seed)
    clips: dict[tuple[int, ...], Clip] = {}
    for _ in range(count * 4):
        if len(clips) >= count:
            break
        frames = _draw_frames(valid_frames, views, gap_min, gap_max, rng)
        if frames is None or frames in clips:
            continue
        n_src = 2 if split == "eval" else int(rng.integers(1, min(3, views - 1) + 1))
        roles = _roles(views, n_src, rng)
        clips[frames] = Clip(frames, roles, max_baseline(positions[list(frames)]))
    return [clips[k] for k in sorted(clips)]


def no_clip_advice(split: str, split_by: str, recordings: int) -> str:
    """Why a clip index split by `split_by` over `recordings` recordings has no `split` clip,
    and what to set (one line, after the path)."""
    if split != "eval":
        return f"no {split!r} clip: every valid view went to eval; lower clips.eval_fraction"
    if split_by == "recording":
        return (f"no 'eval' clip: the clips are split by recording and "
                f"{'the' if recordings == 1 else 'these'} {recordings} recording"
                f"{'' if recordings == 1 else 's'} all went to train; set clips.split: segment "
                "(or auto) to hold out the end of each recording, or add a recording, then run "
                "m3gd run again")
    return ("no 'eval' clip: the eval segments (the last clips.eval_fraction of each recording) "
            "hold no clip of clips.views views; raise clips.eval_fraction or lower clips.views "
            "or clips.gap_max, then run m3gd run again")


def no_clip_message(path: Path, split: str) -> str:
    """`no_clip_advice` for the clip index at `path` (its recorded split and recordings)."""
    import pyarrow.parquet as pq

    from schemas.tables import CLIPS_SPLIT_KEY

    meta = pq.read_schema(path).metadata or {}
    split_by = meta.get(CLIPS_SPLIT_KEY.encode(), b"recording").decode()
    recordings = len(set(pq.read_table(path, columns=["recording"])["recording"].to_pylist()))
    return f"{path}: {no_clip_advice(split, split_by, recordings)}"
