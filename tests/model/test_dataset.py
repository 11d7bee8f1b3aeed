"""Streaming dataset: partitioned across workers, seeded, resumable, reads only what it needs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from model.adapter import scatter_rows
from model.dataset import ClipStream, make_loader, take_clips
from store.shard_reader import ShardReader
from tests.model.cache_fixture import CU, GRID, C, N, build_cache

RECS, CAMS = ("r0", "r1"), ("front", "left")
MEAN = np.array([1.0, -2.0, 3.5, 10.0], np.float32)  # per-channel latent_norm, C = 4
STD = np.array([0.5, 2.0, 4.0, 0.25], np.float32)
_FRAME = np.arange(N, dtype=np.float32)[:, None, None, None]
_CHAN = np.arange(16, dtype=np.float32)[None, :, None, None]
_CELL = np.arange(GRID.grid_h * GRID.grid_w, dtype=np.float32).reshape(1, 1, GRID.grid_h,
                                                                        GRID.grid_w)


def raw_latents(rec: str, cam: str) -> np.ndarray:
    """Stored latents (N, C, H, W): frame code of the fixture plus a channel and cell pattern."""
    code = _FRAME + 1000 * RECS.index(rec) + 100 * CAMS.index(cam)
    return np.broadcast_to(code + 0.5 * _CHAN[:, :C] + 0.125 * _CELL,
                           (N, C, GRID.grid_h, GRID.grid_w)).astype(np.float32)


def planted_mask(rec: str, cam: str) -> np.ndarray:
    """Occupied cells (N, H, W) bool: a pattern that differs per group and frame, never empty."""
    shift = RECS.index(rec) + 2 * CAMS.index(cam)
    mask = (_FRAME[:, 0] + _CELL[0] + shift) % 3 != 0
    return np.broadcast_to(mask, (N, GRID.grid_h, GRID.grid_w))


def planted_g(rec: str, cam: str) -> np.ndarray:
    """Known packet geometry g (N, 6, H, W), distinct per group, frame, channel and cell;
    channel 0 is the validity mask of `planted_mask`, every channel zero where it is 0."""
    base = 7 * RECS.index(rec) + 3 * CAMS.index(cam)
    g = np.broadcast_to(base + 0.25 * _FRAME - _CHAN[:, :6] + 0.5 * _CELL,
                        (N, 6, GRID.grid_h, GRID.grid_w)).astype(np.float32)
    mask = planted_mask(rec, cam)[:, None]
    g = g * mask
    g[:, 0] = mask[:, 0]
    return g


def planted_h(rec: str, cam: str) -> np.ndarray:
    """Known descriptors h (N, C_u, H, W) on occupied cells (zero elsewhere), exact in
    float16 (multiples of 1/8 below 64, never zero on an occupied cell)."""
    base = 5 * RECS.index(rec) + 2 * CAMS.index(cam) + 1
    h = np.broadcast_to(base + 0.5 * _FRAME + 0.125 * (_CHAN[:, :CU] + _CELL),
                        (N, CU, GRID.grid_h, GRID.grid_w))
    return (h * planted_mask(rec, cam)[:, None]).astype(np.float16)


def _plant(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
    arrays["latents_l0"][:] = raw_latents(rec, cam)
    arrays["g"][:] = planted_g(rec, cam)
    arrays["h"][:] = planted_h(rec, cam)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cache")
    build_cache(out, RECS, CAMS, fill=_plant, latent_norm=(MEAN.tolist(), STD.tolist()))
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
    np.testing.assert_array_equal(stream.mean, MEAN)
    np.testing.assert_array_equal(stream.std, STD)
    cameras = set()
    for sample in stream:  # every train clip (both cameras of r0)
        clip = stream.clips[int(sample["clip_id"])]
        rec, cam, frames = clip["recording"], clip["camera"], list(clip["frames"])
        cameras.add(cam)
        raw = raw_latents(rec, cam)[frames]  # (V, C, H, W) as stored
        # the frame code survives normalisation: channel 0, cell 0 is (code - mean_0) / std_0
        code = torch.tensor(frames, dtype=torch.float32) + (100 if cam == "left" else 0)
        assert torch.allclose(sample["latents"][:, 0, 0, 0], (code - 1.0) / 0.5)
        expected = (raw - MEAN[None, :, None, None]) / STD[None, :, None, None]
        assert sample["latents"].dtype == torch.float32
        np.testing.assert_allclose(sample["latents"].numpy(), expected, rtol=1e-6, atol=1e-5)
        assert sample["g"].shape == (4, 6, 2, 3)
        np.testing.assert_array_equal(sample["g"].numpy(), planted_g(rec, cam)[frames])
        dense_h = np.moveaxis(planted_h(rec, cam)[frames], 1, -1)  # channels-last
        occupied = planted_g(rec, cam)[frames][:, 0] > 0.5
        assert sample["h"].dtype == torch.float16  # packed rows of the occupied cells
        np.testing.assert_array_equal(sample["h"].numpy(), dense_h[occupied])
        scattered = scatter_rows(sample["h"], sample["g"][:, 0] > 0.5, torch.float32)
        np.testing.assert_array_equal(scattered.numpy(), dense_h.astype(np.float32))
        assert sample["is_target"].tolist() == [False, True, False, True]
    assert cameras == set(CAMS)


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
    for method in ("read_views", "read_rows"):
        real = getattr(ShardReader, method)

        def spy(self: ShardReader, path: Path, *args, real=real):  # type: ignore[no-untyped-def]
            names.append(path.name)  # every array the reader reads
            return real(self, path, *args)

        monkeypatch.setattr(ShardReader, method, spy)
    sample = next(iter(ClipStream(cache_dir, "train", mode="geom_only")))
    assert "h" not in sample and "g" in names
    assert "h_cells" not in names
    next(iter(ClipStream(cache_dir, "train", mode="no_lidar")))
    assert names.count("g") == 1
    next(iter(ClipStream(cache_dir, "train", mode="full")))
    assert "h_cells" in names


def test_dense_h_on_request_and_packed_batches(cache_dir: Path) -> None:
    """dense_h=True gives the dense channels-last h; a batch of packed clips scatters to the
    same dense batch (rows concatenated in the batch's occupancy order)."""
    dense = ClipStream(cache_dir, "train", shuffle=False, dense_h=True)
    packed = ClipStream(cache_dir, "train", shuffle=False)
    batch_d = next(iter(make_loader(dense, 3)))
    batch_p = next(iter(make_loader(packed, 3)))
    assert batch_d["h"].shape == (3, 4, 2, 3, CU) and batch_d["h"].dtype == torch.float32
    assert batch_p["h"].ndim == 2
    scattered = scatter_rows(batch_p["h"], batch_p["g"][:, :, 0] > 0.5, torch.float32)
    torch.testing.assert_close(scattered, batch_d["h"], rtol=0, atol=0)
    first = take_clips(batch_p, 2)  # the first clips of a packed batch
    scattered = scatter_rows(first["h"], first["g"][:, :, 0] > 0.5, torch.float32)
    torch.testing.assert_close(scattered, batch_d["h"][:2], rtol=0, atol=0)


def _valid_half(rec: str, cam: str, arrays: dict[str, np.ndarray]) -> None:
    arrays["valid"][::2] = True  # N // 2 valid views per group


def test_a_latent_norm_of_other_valid_views_is_refused_in_one_line(tmp_path: Path) -> None:
    """Was: a normalization computed over other views than the cache holds (e.g. after a
    `cache.shard_views` change) was used silently by every training run. The view counts it
    recorded per group are checked against the cache streamed: a mismatch, an uncovered
    group or a normalization without counts is refused naming the file and what to run."""
    import json

    from schemas.errors import DataError
    from store.cache_io import write_views

    build_cache(tmp_path, RECS, CAMS, fill=_valid_half)
    root = tmp_path / "cache.zarr" / "zarr.json"
    norm = json.loads(root.read_text())["attributes"]["latent_norm"]
    assert norm["groups"] == {f"{r}/{c}": N // 2 for r in RECS for c in CAMS}
    assert len(ClipStream(tmp_path, "train").clips) > 0  # the recorded counts hold
    write_views(tmp_path / "cache.zarr" / "r1" / "left" / "valid", 1, np.ones(1, bool))
    with pytest.raises(DataError) as err:
        ClipStream(tmp_path, "train")  # a group of the other split changed: refused too
    line = str(err.value)
    assert "\n" not in line and line.startswith(f"{root}: latent_norm was computed over "
                                                f"{N // 2} valid views of r1/left, which "
                                                f"now holds {N // 2 + 1}; m3gd run ")
    assert "--force stats" in line
    write_views(tmp_path / "cache.zarr" / "r1" / "left" / "valid", 1, np.zeros(1, bool))
    meta = json.loads(root.read_text())
    del meta["attributes"]["latent_norm"]["groups"]["r0/front"]
    root.write_text(json.dumps(meta))
    with pytest.raises(DataError, match=r"latent_norm does not cover r0/front, whose clips "
                                        r"are read; m3gd run"):
        ClipStream(tmp_path, "train")
    assert len(ClipStream(tmp_path, "eval").clips) > 0  # r1 only: covered, counts equal
    meta["attributes"]["latent_norm"] = {"mean": [0.0] * C, "std": [1.0] * C}
    root.write_text(json.dumps(meta))
    with pytest.raises(DataError, match=r"zarr.json: latent_norm was recorded without its "
                                        r"view counts \(an earlier format\); m3gd run"):
        ClipStream(tmp_path, "eval")
