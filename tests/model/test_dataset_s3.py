"""ClipStream over an output on S3 (a moto server): the same samples as from local disk,
array for array, through a bounded read-through shard cache; sharding unchanged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from model.dataset import ClipStream, make_loader
from store.object_store import StorageError, parse_url
from store.shard_cache import ShardCache, chunk_keys
from tests.model.cache_fixture import build_cache
from tests.model.test_dataset import CAMS, MEAN, RECS, STD, _plant
from tests.s3_fixture import upload


@pytest.fixture(scope="module")
def local_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cache")
    build_cache(out, RECS, CAMS, fill=_plant, latent_norm=(MEAN.tolist(), STD.tolist()))
    return out


@pytest.fixture
def remote_out(s3: str, local_out: Path) -> str:
    upload(local_out, s3)
    return s3


def _cache(url: str, root: Path, limit: int) -> ShardCache:
    return ShardCache(parse_url(url), root, limit)


def _assert_same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert a[key].dtype == b[key].dtype, key
        np.testing.assert_array_equal(a[key].numpy(), b[key].numpy(), err_msg=key)


@pytest.mark.parametrize("mode", ["full", "geom_only"])
def test_s3_stream_equals_local(remote_out: str, local_out: Path, tmp_path: Path,
                                mode: str) -> None:
    for split in ("train", "eval"):
        local = list(ClipStream(local_out, split, mode, seed=2, with_images=True))
        remote = ClipStream(remote_out, split, mode, seed=2, with_images=True,
                            remote=_cache(remote_out, tmp_path / split, 2**30))
        got = list(remote)
        assert len(got) == len(local) > 0
        for a, b in zip(local, got, strict=True):
            _assert_same(a, b)
        stats = remote.remote.stats if remote.remote else {}
        assert stats["misses"] > 0 and stats["hits"] > 0  # clips share shards


def test_eviction_keeps_bytes_bounded_and_data_equal(remote_out: str, local_out: Path,
                                                     tmp_path: Path) -> None:
    cache = _cache(remote_out, tmp_path / "mirror", limit=1)  # evicts all but the clip's
    stream = ClipStream(remote_out, "train", seed=1, remote=cache)
    local = ClipStream(local_out, "train", seed=1)
    for epoch in range(2):
        stream.set_epoch(epoch)
        local.set_epoch(epoch)
        for a, b in zip(local, stream, strict=True):
            _assert_same(a, b)
            # after a read only the objects of at most one clip remain
            assert len(cache.shard_files()) <= 4 * 6
    assert cache.stats["evicted"] > 0


def test_second_epoch_hits_when_everything_fits(remote_out: str, tmp_path: Path) -> None:
    cache = _cache(remote_out, tmp_path / "mirror", limit=2**30)
    stream = ClipStream(remote_out, "train", seed=1, remote=cache)
    list(stream)
    first = dict(cache.stats)
    stream.set_epoch(1)
    list(stream)
    assert cache.stats["misses"] == first["misses"]  # no new fetch
    assert cache.stats["gets"] == first["gets"]
    assert cache.stats["hits"] > first["hits"]


def test_ranks_partition_like_local(remote_out: str, local_out: Path, tmp_path: Path) -> None:
    for rank in range(2):
        remote = ClipStream(remote_out, "train", seed=1, rank=rank, world_size=2,
                            remote=_cache(remote_out, tmp_path / "m", 2**30))
        local = ClipStream(local_out, "train", seed=1, rank=rank, world_size=2)
        assert [int(s["clip_id"]) for s in remote] == [int(s["clip_id"]) for s in local]


def test_loader_workers_share_one_mirror(remote_out: str, local_out: Path,
                                         tmp_path: Path) -> None:
    stream = ClipStream(remote_out, "train", seed=3, remote=_cache(remote_out, tmp_path, 1))
    ids = [i for b in make_loader(stream, 3, 2) for i in b["clip_id"].tolist()]
    local = [i for b in make_loader(ClipStream(local_out, "train", seed=3), 3, 2)
             for i in b["clip_id"].tolist()]
    assert ids == local


def test_chunk_keys_default_and_v2() -> None:
    meta = {"shape": [24, 6, 2, 3], "chunk_grid": {"configuration": {"chunk_shape": [8, 6, 2,
                                                                                      3]}}}
    assert chunk_keys(meta, [7, 8, 9]) == ["c/0/0/0/0", "c/1/0/0/0"]
    meta["chunk_key_encoding"] = {"name": "v2", "configuration": {"separator": "."}}
    meta["chunk_grid"]["configuration"]["chunk_shape"] = [8, 3, 2, 3]
    assert chunk_keys(meta, [23]) == ["2.0.0.0", "2.1.0.0"]


def test_missing_bucket_is_one_line(s3: str) -> None:
    url = s3.replace("m3gd-test", "m3gd-none")
    with pytest.raises(StorageError, match=r"^s3://m3gd-none-\d+/out .*no such bucket [^\n]*$"):
        ClipStream(url, "train")


def test_secret_never_written(remote_out: str, tmp_path: Path,
                              caplog: pytest.LogCaptureFixture) -> None:
    import logging
    import os
    import pickle

    secret = os.environ["AWS_SECRET_ACCESS_KEY"]
    caplog.set_level(logging.DEBUG)
    stream = ClipStream(remote_out, "train", remote=_cache(remote_out, tmp_path, 2**30))
    list(stream)
    assert secret not in caplog.text
    assert secret.encode() not in pickle.dumps(stream)  # what DataLoader workers receive
    for path in tmp_path.rglob("*"):
        if path.is_file():
            assert secret.encode() not in path.read_bytes(), path


def test_metadata_mirrored_for_checks(remote_out: str, tmp_path: Path) -> None:
    from model.scoring import check_mode

    stream = ClipStream(remote_out, "train", "full", remote=_cache(remote_out, tmp_path, 1))
    check_mode(stream)  # reads the arrays' zarr.json in the mirror: fetched up front
    where, attrs = stream.first_group()
    assert (where / "h_cells" / "zarr.json").exists() and attrs.shard_views == 8
