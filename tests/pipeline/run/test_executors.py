"""Executors: LocalCluster workers pinned one per core; items run single-threaded."""

from __future__ import annotations

import os

import pytest
import torch
from threadpoolctl import threadpool_info

from pipeline.run.executors import DaskExecutor, single_threaded

pytestmark = pytest.mark.filterwarnings("ignore")


def _affinity() -> list[int]:
    return sorted(os.sched_getaffinity(0))


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs 2 cores")
def test_local_cluster_workers_pinned_to_distinct_cores() -> None:
    executor = DaskExecutor(workers=2)
    try:
        masks = list(executor.client.run(_affinity).values())
    finally:
        executor.close()
    assert sorted(len(m) for m in masks) == [1, 1]
    assert masks[0] != masks[1]


def test_single_threaded_limits_blas_and_torch_then_restores() -> None:
    before = torch.get_num_threads()
    with single_threaded():
        assert torch.get_num_threads() == 1
        assert all(i["num_threads"] == 1 for i in threadpool_info()
                   if i["user_api"] in ("blas", "openmp"))
    assert torch.get_num_threads() == before
