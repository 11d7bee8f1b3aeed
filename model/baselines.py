"""Image baselines built from training views: the per-pixel mean training image and the
per-recording mean image.

Scored beside the model on every target (`model.evaluate.synthesize_targets`):
  mean_image             the per-pixel mean of the training views (uint8-rounded): the
                         best constant image in squared error, so it keeps the layout
                         (floor below, sky above) that the mean latent loses;
  recording_mean         the per-pixel mean of the training views of the target's own
                         recording (its clip's views excluded); it exists only where a
                         recording's other views are training views: under the
                         segment split (`clips.split`), not under the recording split;
  recording_mean_oracle  the same mean over every other view of the target's recording,
                         training or not: it looks at held-out views the model never sees,
                         so it is reported for reference only and never counts as the
                         strongest baseline.
Training views: the views of the training split's clips, optionally restricted to some
recordings (the science bench holds two training recordings out for validation).
The training mean reads at most `MAX_MEAN_VIEWS` views, evenly strided over the groups.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from schemas.cache_layout import GROUP_TEMPLATE, GroupAttrs
from schemas.layout import OutputLayout
from store.cache_io import node_attrs, read_clip

MAX_MEAN_VIEWS = 4096
"""Views averaged into the training mean image at most (evenly strided)."""
IMAGE_BASELINES = ("mean_image", "recording_mean", "recording_mean_oracle")
"""Baselines of this module, in table order."""
ORACLE_BASELINES = ("recording_mean_oracle",)
"""Baselines that look at held-out views: reported, never the strongest."""


@dataclass
class GroupSums:
    """Float64 sums (h, w, 3) of one recording-camera group's views: every view, and the
    training views (their frame indices in `train_frames`)."""

    all_sum: np.ndarray
    all_count: int
    train_sum: np.ndarray
    train_frames: frozenset[int] = field(default_factory=frozenset)


@dataclass
class MeanImages:
    """The training mean image (h, w, 3) float64 and per-group sums for the recording means."""

    train_mean: np.ndarray
    train_views: int
    groups: dict[str, GroupSums]

    def references(self, clip: dict[str, Any], images: np.ndarray) -> dict[str, np.ndarray]:
        """The baseline images (h, w, 3) uint8 for one clip (a clip-index row with recording,
        camera, frames) whose views' images are `images` (V, h, w, 3) uint8 in frame order.

        A recording mean is left out when no view of the recording outside the clip exists.
        """
        out = {"mean_image": to_uint8(self.train_mean)}
        sums = self.groups.get(GROUP_TEMPLATE.format(recording=clip["recording"],
                                                     camera=clip["camera"]))
        if sums is None:
            return out
        frames = [int(f) for f in clip["frames"]]
        unique = {f: i for i, f in enumerate(frames)}  # a frame listed twice counts once
        clip_sum = images[list(unique.values())].astype(np.float64).sum(axis=0)
        others = sums.all_count - len(unique)
        if others > 0:
            out["recording_mean_oracle"] = to_uint8((sums.all_sum - clip_sum) / others)
        in_train = [i for f, i in unique.items() if f in sums.train_frames]
        n_train = len(sums.train_frames) - len(in_train)
        if n_train > 0:
            own = images[in_train].astype(np.float64).sum(axis=0) if in_train else 0.0
            out["recording_mean"] = to_uint8((sums.train_sum - own) / n_train)
        return out


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Round a float image in [0, 255] to uint8."""
    out: np.ndarray = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return out


def training_frames(clips: Iterable[dict[str, Any]], recordings: set[str] | None
                    ) -> dict[str, set[int]]:
    """Group path -> frames of the training clips (of `recordings` only, when given)."""
    out: dict[str, set[int]] = {}
    for c in clips:
        if recordings is not None and c["recording"] not in recordings:
            continue
        group = GROUP_TEMPLATE.format(recording=c["recording"], camera=c["camera"])
        out.setdefault(group, set()).update(int(f) for f in c["frames"])
    return out


def strided(items: Sequence[tuple[str, int]], limit: int) -> list[tuple[str, int]]:
    """At most `limit` items, evenly strided (all when fewer)."""
    if len(items) <= limit:
        return list(items)
    idx = np.linspace(0, len(items) - 1, limit).round().astype(int)
    return [items[i] for i in sorted(set(idx.tolist()))]


def _read(cache: Path, group: str, frames: list[int], chunk: int = 64) -> Iterable[np.ndarray]:
    """Images (k, h, w, 3) uint8 of `frames` of one group, `chunk` views at a time."""
    for i in range(0, len(frames), chunk):
        yield read_clip(cache / group, ["images"], frames[i:i + chunk])["images"]


def build_mean_images(output_dir: Path, groups: Iterable[str],
                      train_recordings: set[str] | None = None) -> MeanImages:
    """Training mean image and the sums of `groups` (the groups of the scored clips).

    train_recordings: the recordings whose training-split views count as training views
    (None: every recording of the training split).
    """
    from model.dataset import load_clips

    cache = OutputLayout(output_dir).cache
    train = training_frames(load_clips(output_dir, "train"), train_recordings)
    if not train:
        raise ValueError(f"{output_dir}: no training view for the mean-image baselines")
    views = strided([(g, f) for g in sorted(train) for f in sorted(train[g])], MAX_MEAN_VIEWS)
    total: np.ndarray | None = None
    for g in sorted({g for g, _ in views}):
        for imgs in _read(cache, g, [f for gg, f in views if gg == g]):
            s = imgs.astype(np.float64).sum(axis=0)
            total = s if total is None else total + s
    assert total is not None
    sums: dict[str, GroupSums] = {}
    for g in sorted(set(groups)):
        n = GroupAttrs.from_attrs(node_attrs(cache / g), str(cache / g)).n_views
        all_sum = sum(imgs.astype(np.float64).sum(axis=0) for imgs in _read(cache, g,
                                                                            list(range(n))))
        tf = sorted(train.get(g, set()))
        train_sum = (sum(imgs.astype(np.float64).sum(axis=0) for imgs in _read(cache, g, tf))
                     if tf else np.zeros_like(total))
        sums[g] = GroupSums(np.asarray(all_sum), n, np.asarray(train_sum), frozenset(tf))
    return MeanImages(total / len(views), len(views), sums)


_CACHE: dict[tuple[str, frozenset[str] | None, tuple[str, ...]], MeanImages] = {}


def mean_images_for(output_dir: Path, clips: Iterable[dict[str, Any]],
                    train_recordings: set[str] | None = None) -> MeanImages:
    """`build_mean_images` for the groups of `clips`, memoized per process (the science
    bench scores the same targets many times)."""
    groups = tuple(sorted({GROUP_TEMPLATE.format(recording=c["recording"], camera=c["camera"])
                           for c in clips}))
    key = (str(output_dir), None if train_recordings is None else frozenset(train_recordings),
           groups)
    if key not in _CACHE:
        _CACHE[key] = build_mean_images(output_dir, groups, train_recordings)
    return _CACHE[key]
