"""Errors survive every executor: each M3GDError class round-trips through pickle, cloudpickle
and dask.distributed (a LocalCluster on 127.0.0.1), raised or returned as a value."""

from __future__ import annotations

import copy
import pickle
from collections.abc import Iterator
from typing import Any

import cloudpickle
import pytest
import tblib.pickling_support
from distributed.protocol.pickle import dumps, loads

from pipeline.run.executors import portable
from schemas.errors import DataError, M3GDError, MissingInputError
from tests.pipeline.run import error_cases
from tests.pipeline.run.error_cases import UnpicklableCause, class_name, error_classes, same, sample

NAMES = [class_name(c) for c in error_classes()]


def test_the_error_classes_are_found() -> None:
    # the classes the issue named, and the ones with their own __init__ (the hard cases)
    for name in ("schemas.errors:MissingInputError", "schemas.config:ConfigError",
                 "pipeline.ingest.errors:RowReject", "model.train_step:DivergedError",
                 "model.loop:TrainingDiverged", "pipeline.run.lock:LockHeld"):
        assert name in NAMES
    assert all(issubclass(c, M3GDError) for c in error_classes())


@pytest.mark.parametrize("name", NAMES)
def test_round_trips_through_pickle_and_cloudpickle(name: str) -> None:
    err = sample(name)
    for protocol in range(2, pickle.HIGHEST_PROTOCOL + 1):
        assert same(pickle.loads(pickle.dumps(err, protocol)), err), protocol
    assert same(cloudpickle.loads(cloudpickle.dumps(err)), err)
    assert same(copy.copy(err), err)


@pytest.mark.parametrize("name", NAMES)
def test_round_trips_through_distributed_pickle_with_tblib(name: str) -> None:
    """As a Dask worker sends a failed task's error: tblib's reducer registered for the error
    and its cause (distributed.core.error_message), then distributed's pickle."""
    err = sample(name)
    tblib.pickling_support.install(err, err.__cause__)
    back = loads(dumps(err))
    assert same(back, err)
    assert isinstance(back.__cause__, KeyError) and back.__traceback__ is not None


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    from distributed import Client, LocalCluster

    cloudpickle.register_pickle_by_value(error_cases)
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None, scheduler_kwargs={"dashboard_address": ":0"})
    with Client(cluster) as c:
        yield c
    cluster.close()
    cloudpickle.unregister_pickle_by_value(error_cases)


@pytest.mark.filterwarnings("ignore")
def test_every_class_comes_back_from_a_worker_raised_and_as_a_value(client: Any) -> None:
    for name in NAMES:
        with pytest.raises(M3GDError) as info:
            client.submit(error_cases.raise_sample, name, pure=False).result()
        assert same(info.value, sample(name)), name
        # a permanent error comes back as a value (pipeline.run.executors._Permanent)
        assert same(client.submit(sample, name, pure=False).result(), sample(name)), name


def test_an_error_whose_cause_does_not_pickle_keeps_its_type_and_message() -> None:
    try:
        raise MissingInputError("/m: no ROS1 .bag files") from UnpicklableCause("a lock inside")
    except MissingInputError as caught:
        err = caught
    out = portable(err)
    assert same(loads(dumps(out)), MissingInputError("/m: no ROS1 .bag files"))


def test_an_error_that_does_not_pickle_at_all_becomes_a_data_error_naming_it() -> None:
    out = portable(UnpicklableCause("a lock inside"))
    assert type(out) is DataError and str(out) == "UnpicklableCause: a lock inside"
