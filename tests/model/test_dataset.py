"""Streaming dataset: partitioned across workers, seeded, resumable, reads only what it needs."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch.utils.data import DataLoader

import model.dataset as dataset_mod
from model.dataset import ClipStream, make_loader
from tests.model.cache_fixture import build_cache


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cache")
    build_cache(out)
    return out


def _ids(loader: DataLoader, stream: ClipStream | None = None) -> list[int]:
    ids = []
    for batch in loader:
        ids.extend(batch["clip_id"].tolist())
        if stream is not None:
            stream.update(batch)
    return ids


def test_latents_match_frames(cache_dir: Path) -> None:
    stream = ClipStream(cache_dir, "train", shuffle=False)
    sample = next(iter(stream))
    clip = stream.clips[int(sample["clip_id"])]
    expected = torch.tensor(clip["frames"], dtype=torch.float32) + (100 if clip["camera"] == "left"
                                                                     else 0)
    assert torch.equal(sample["latents"][:, 0, 0, 0], expected)
    assert sample["h"].shape == (4, 3, 2, 3) and sample["g"].shape == (4, 6, 2, 3)
    assert sample["is_target"].tolist() == [False, True, False, True]


def test_workers_partition_without_duplicates(cache_dir: Path) -> None:
    stream = ClipStream(cache_dir, "train", seed=3)
    ids = _ids(make_loader(stream, 3, 2))
    assert sorted(ids) == list(range(len(stream.clips)))
    again = _ids(make_loader(ClipStream(cache_dir, "train", seed=3), 3, 2))
    other = _ids(make_loader(ClipStream(cache_dir, "train", seed=4), 3, 2))
    assert ids == again and ids != other


def test_ranks_partition_without_duplicates(cache_dir: Path) -> None:
    seen = []
    for rank in range(2):
        stream = ClipStream(cache_dir, "train", seed=1, rank=rank, world_size=2)
        seen.extend(int(s["clip_id"]) for s in stream)
    assert sorted(seen) == sorted({c["clip_id"] for c in ClipStream(cache_dir, "train").clips})


def test_resume_mid_epoch(cache_dir: Path) -> None:
    full = _ids(make_loader(ClipStream(cache_dir, "train", seed=5), 2, 2))
    stream = ClipStream(cache_dir, "train", seed=5)
    loader = make_loader(stream, 2, 2)
    first = []
    for i, batch in enumerate(loader):
        first.extend(batch["clip_id"].tolist())
        stream.update(batch)
        if i == 2:
            break
    state = stream.state_dict()
    resumed = ClipStream(cache_dir, "train", seed=5)
    resumed.load_state_dict(state)
    rest = _ids(make_loader(resumed, 2, 2))
    assert sorted(first + rest) == sorted(full)
    assert not set(first) & set(rest)


def test_geom_only_never_reads_h(cache_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    names: list[str] = []
    real = dataset_mod.read_many

    def spy(paths: list[Path], frames: list[int]):  # type: ignore[no-untyped-def]
        names.extend(p.name for p in paths)
        return real(paths, frames)

    monkeypatch.setattr(dataset_mod, "read_many", spy)
    sample = next(iter(ClipStream(cache_dir, "train", mode="geom_only")))
    assert "h" not in sample and "h" not in names and "g" in names
    next(iter(ClipStream(cache_dir, "train", mode="no_lidar")))
    assert names.count("g") == 1
