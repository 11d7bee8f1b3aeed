"""Clip sampling (pure): V views of one recording and camera, sources and targets.

A clip is V distinct frames in increasing order whose consecutive gaps lie in
[gap_min, gap_max] frames, all valid views. Training clips have 1-3 sources
(the rest targets); evaluation clips exactly 2 sources and 2 targets (V = 4).
The recording split is made first, so no recording is in both splits.
"""

from __future__ import annotations

from dataclasses import dataclass

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
