"""Streaming clips from the Zarr cache: a torch IterableDataset over shards.

Work units are shard groups: the clips whose first frame lies in one shard of one
recording-camera group, so a worker reads few shards. Units are shuffled per
epoch with a seeded permutation and dealt round-robin to every (rank, DataLoader
worker) pair, so no clip is read twice. Each sample carries `_worker` and `_seq`;
`ClipStream.update(batch)` turns consumed samples into a state dict from which a
new stream resumes mid-epoch exactly. Only the arrays the packet mode needs are
read (geom-only never touches h).

Packet features h are handed over packed, as stored: "h" is (sum_v k_v, C_u) float16, the
occupied cells' rows of the clip's views (view after view, row-major cells), placed by the
validity channel of "g" (schemas.packed_cells); `collate_clips` stacks them batch after
batch, so a batch's rows follow the occupancy g[:, :, 0] > 0.5 of the (B, V, ...) batch and
the adapter scatters them (model.adapter.build_packet). `dense_h=True` gives dense
channels-last (V, H, W, C_u) float32 instead. One `ShardReader` per stream (per DataLoader
worker after the spawn) keeps shard files open and their indexes parsed.

`output_dir` may be an `s3://bucket/prefix` URL: the clip index, metadata and the shard
objects clips need are then read through a bounded local read-through cache
(store.shard_cache), with the same sharding over ranks and workers.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import torch
from torch.utils.data import IterableDataset, default_collate, get_worker_info

from schemas.cache_layout import (
    GROUP_TEMPLATE,
    H_CELLS,
    GroupAttrs,
    LatentNorm,
    check_root_attrs,
)
from schemas.errors import DataError
from schemas.layout import CACHE_DIRNAME, CLIPS_FILENAME, OutputLayout
from schemas.modes import MODE_ARRAYS
from schemas.tables import CLIPS, check_schema
from store.cache_io import node_attrs, read_clip
from store.shard_cache import ShardCache, open_remote
from store.shard_reader import ShardReader

NEEDS = MODE_ARRAYS
READ_ARRAYS = ("latents_l0", "K", "T_world_cam", "g", H_CELLS, "images", "valid")
"""Arrays a stream may read (metadata mirrored up front for an output on S3); `valid`: the
valid views the latent normalization is checked against."""
RECOMPUTE = "m3gd run recomputes it (m3gd run --force stats if the run is up to date)"


@dataclass
class StreamState:
    """Resumable position: epoch and samples consumed per global worker."""

    epoch: int = 0
    consumed: dict[int, int] = field(default_factory=dict)


def load_clips(output_dir: Path, split: str) -> list[dict[str, Any]]:
    """Rows of the clip index for `split` (a list of dicts)."""
    path = OutputLayout(output_dir).clips
    check_schema(pq.read_schema(path), CLIPS, str(path))
    table = pq.read_table(path)
    return [r for r in table.to_pylist() if r["split"] == split]


def latent_norm(cache: Path, valid_views: Callable[[str], int | None],
                streamed: Iterable[str] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel mean and std (C,) float32 stored by the stats stage in the root attrs,
    refused in one line unless it describes the cache read now: the valid views it recorded
    per group equal `valid_views(group)` (None: gone) and it covers every `streamed` group."""
    attrs = node_attrs(cache)
    check_root_attrs(attrs, str(cache))
    raw = attrs.get("latent_norm")
    where = cache / "zarr.json"
    if raw is None:
        raise DataError(f"{cache}: no latent_norm attribute; run the stats stage first")
    norm = LatentNorm.from_attrs(raw)
    if norm is None:
        raise DataError(f"{where}: latent_norm was recorded without its view counts (an "
                        f"earlier format); {RECOMPUTE}")
    why = norm.stale_against({g: valid_views(g) for g in norm.groups})
    uncovered = sorted(set(streamed) - set(norm.groups))
    if why is None and uncovered:
        why = f"latent_norm does not cover {uncovered[0]}, whose clips are read"
    if why is not None:
        raise DataError(f"{where}: {why}; {RECOMPUTE}")
    return np.asarray(norm.mean, np.float32), np.asarray(norm.std, np.float32)


class ClipStream(IterableDataset[dict[str, torch.Tensor]]):
    """Clips of one split, streamed from the cache shards."""

    def __init__(self, output_dir: Path | str, split: str = "train", mode: str = "full",
                 seed: int = 0, shuffle: bool = True, rank: int = 0, world_size: int = 1,
                 with_images: bool = False, dense_h: bool = False,
                 remote: ShardCache | None = None) -> None:
        """`remote`: the read-through cache for an `s3://` output_dir (default: one in
        $M3GD_SHARD_CACHE or the temp dir, limited to 20 GiB of shards)."""
        if mode not in NEEDS:
            raise DataError(f"unknown packet mode {mode!r}; one of {sorted(NEEDS)}")
        self.remote = remote or open_remote(output_dir)
        output_dir = self.remote.root if self.remote else Path(output_dir)
        self.cache = OutputLayout(output_dir).cache
        if self.remote:
            self.remote.fetch(CLIPS_FILENAME)
            self.remote.fetch(f"{CACHE_DIRNAME}/zarr.json")
        self.clips = load_clips(output_dir, split)
        self.mode, self.seed, self.shuffle = mode, seed, shuffle
        self.rank, self.world_size, self.with_images = rank, world_size, with_images
        self.dense_h = dense_h
        self.reader = ShardReader()  # handles are not pickled: each worker opens its own
        self.state = StreamState()
        if self.remote is not None:  # metadata: small, kept in the mirror
            for g in self._groups():
                for node in (g, *(f"{g}/{a}" for a in READ_ARRAYS)):
                    self.remote.fetch(f"{CACHE_DIRNAME}/{node}/zarr.json")
        self.mean, self.std = latent_norm(self.cache, self._valid_views, self._groups())
        self._shard_views = {g: self._attrs(g).shard_views for g in self._groups()}

    def _groups(self) -> list[str]:
        """Group paths that clips refer to."""
        names = {GROUP_TEMPLATE.format(recording=c["recording"], camera=c["camera"])
                 for c in self.clips}
        return sorted(names)

    def _valid_views(self, group: str) -> int | None:
        """Valid views of a cache group now (its `valid` array), None when it is gone."""
        folder = self.cache / group
        if self.remote is not None:
            self.remote.fetch(f"{CACHE_DIRNAME}/{group}/valid/zarr.json")
        meta = folder / "valid" / "zarr.json"
        if not meta.exists():
            return None
        frames = list(range(int(json.loads(meta.read_text())["shape"][0])))
        with self._holding(folder, ["valid"], frames):
            valid = read_clip(folder, ["valid"], frames, self.reader)["valid"]
        return int(np.count_nonzero(valid))

    def _attrs(self, group: str) -> GroupAttrs:
        """Attributes of one cache group (version-checked)."""
        return GroupAttrs.from_attrs(node_attrs(self.cache / group), str(self.cache / group))

    def first_group(self) -> tuple[Path, GroupAttrs]:
        """Directory and attributes of the cache group of the first clip (the cache's sizes)."""
        if not self.clips:
            raise DataError(f"{self.cache}: no clip in this split")
        clip = self.clips[0]
        group = GROUP_TEMPLATE.format(recording=clip["recording"], camera=clip["camera"])
        return self.cache / group, self._attrs(group)

    def units(self, epoch: int) -> list[list[int]]:
        """Clip indices grouped by shard unit, in this epoch's order."""
        by_unit: dict[tuple[str, int], list[int]] = {}
        for i, c in enumerate(self.clips):
            group = GROUP_TEMPLATE.format(recording=c["recording"], camera=c["camera"])
            key = (group, min(c["frames"]) // self._shard_views[group])
            by_unit.setdefault(key, []).append(i)
        keys = sorted(by_unit)
        rng = np.random.default_rng([self.seed, epoch])
        order = rng.permutation(len(keys)) if self.shuffle else np.arange(len(keys))
        units = []
        for k in order:
            members = list(by_unit[keys[k]])
            if self.shuffle:
                members = [members[j] for j in rng.permutation(len(members))]
            units.append(members)
        return units

    def epoch_order(self, epoch: int) -> list[int]:
        """Every clip index once, in this epoch's order (units in order; `model.batching`)."""
        return [i for u in self.units(epoch) for i in u]

    def worker_clips(self, epoch: int, worker: int, total: int) -> list[int]:
        """Clip indices of one global worker in order for an epoch."""
        units = self.units(epoch)
        return [i for u in units[worker::total] for i in u]

    def set_epoch(self, epoch: int) -> None:
        """Start `epoch` from its beginning."""
        self.state = StreamState(epoch)

    def update(self, batch: dict[str, torch.Tensor]) -> None:
        """Record the samples of a consumed batch (call in the training loop)."""
        for w, s in zip(batch["_worker"].tolist(), batch["_seq"].tolist(), strict=True):
            self.state.consumed[w] = max(self.state.consumed.get(w, 0), s + 1)

    def state_dict(self) -> dict[str, Any]:
        """JSON-compatible resumable state."""
        return {"epoch": self.state.epoch,
                "consumed": {str(k): v for k, v in self.state.consumed.items()}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Resume from `state_dict()` output."""
        consumed = {int(k): int(v) for k, v in state["consumed"].items()}
        self.state = StreamState(int(state["epoch"]), consumed)

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        info = get_worker_info()
        n_workers, wid = (info.num_workers, info.id) if info is not None else (1, 0)
        if info is not None:
            torch.set_num_threads(1)
        total = n_workers * self.world_size
        worker = self.rank * n_workers + wid
        mine = self.worker_clips(self.state.epoch, worker, total)
        start = self.state.consumed.get(worker, 0)
        for seq in range(start, len(mine)):
            sample = self.read_clip(self.clips[mine[seq]])
            sample["_worker"] = torch.tensor(worker)
            sample["_seq"] = torch.tensor(seq)
            yield sample

    def read_clip(self, clip: dict[str, Any]) -> dict[str, torch.Tensor]:
        """Read one clip's arrays: normalized latents, packets per mode, cameras, roles."""
        group = self.cache / GROUP_TEMPLATE.format(recording=clip["recording"],
                                                   camera=clip["camera"])
        frames = list(clip["frames"])
        packets = [n if n != "h" or self.dense_h else "h_rows" for n in NEEDS[self.mode]]
        names = ["latents_l0", "K", "T_world_cam", *packets]
        names += ["images"] if self.with_images else []
        with self._holding(group, names, frames):
            arrays = read_clip(group, names, frames, self.reader)
        lat = torch.from_numpy(arrays.pop("latents_l0")).float()  # torch casts f16 ~5x faster
        out = {
            "latents": ((lat - torch.from_numpy(self.mean)[None, :, None, None])
                        / torch.from_numpy(self.std)[None, :, None, None]),
            "K": torch.from_numpy(arrays.pop("K").astype(np.float32)),
            "T_world_cam": torch.from_numpy(arrays.pop("T_world_cam")),
            "is_target": torch.tensor(clip["is_target"]),
            "clip_id": torch.tensor(clip["clip_id"]),
        }
        if self.with_images:
            out["images"] = torch.from_numpy(arrays.pop("images"))
        if "h_rows" in arrays:  # (sum_v k_v, C_u) float16, cast where it is scattered
            out["h"] = torch.from_numpy(arrays.pop("h_rows"))
        for name, data in arrays.items():  # g; dense h (V, H, W, C_u) channels-last
            out[name] = torch.from_numpy(data).float()
        return out


    def _holding(self, group: Path, names: list[str], frames: list[int]
                 ) -> AbstractContextManager[None]:
        """Keep the shard objects of a clip read in the local mirror (no-op for local data)."""
        if self.remote is None:
            return nullcontext()
        rel = str(group.relative_to(self.remote.root))
        return self.remote.holding(self.remote.view_objects(rel, names, frames))


def collate_clips(samples: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """A batch of clip samples: every entry stacked on a new batch axis, except packed h
    (2-D rows) which is concatenated, sample after sample (the batch's occupancy order)."""
    packed = bool(samples) and "h" in samples[0] and samples[0]["h"].ndim == 2
    batch: dict[str, torch.Tensor] = default_collate(
        [{k: v for k, v in s.items() if not (packed and k == "h")} for s in samples])
    if packed:
        batch["h"] = torch.cat([s["h"] for s in samples])
    return batch


def take_clips(batch: dict[str, torch.Tensor], n: int) -> dict[str, torch.Tensor]:
    """The first `n` clips of a batch; packed h keeps the rows of those clips' occupied
    cells (the first rows: they are stored clip after clip)."""
    out = {k: v[:n] for k, v in batch.items()}
    if "h" in batch and batch["h"].ndim == 2:
        out["h"] = batch["h"][:int((batch["g"][:n, :, 0] > 0.5).sum())]
    return out


def make_loader(stream: ClipStream, batch_size: int, num_workers: int = 0) -> Any:
    """A DataLoader over `stream`; workers are spawned (tensorstore forbids fork)."""
    from torch.utils.data import DataLoader

    ctx = "spawn" if num_workers > 0 else None
    return DataLoader(stream, batch_size=batch_size, num_workers=num_workers,
                      multiprocessing_context=ctx, persistent_workers=False,
                      collate_fn=collate_clips)
