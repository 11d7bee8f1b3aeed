"""Where stage items run: in-process, or on a dask.distributed cluster (local or remote).

Both executors yield `(item key, ItemResult or the final exception)` as items
finish; a failing item is retried `retries` times before its error is reported,
except for data errors (`schemas.errors.DataError`), which fail the same way on every try
and are reported at once.
"""

from __future__ import annotations

import contextlib
import logging
import os
import uuid
from collections.abc import Callable, Iterator
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin
from threadpoolctl import threadpool_limits

from pipeline.run.keys import ItemKey
from pipeline.run.stage import Item, ItemResult
from schemas.config import M3GDConfig
from schemas.errors import DataError

log = logging.getLogger(__name__)

RunFn = Callable[[M3GDConfig, Item], ItemResult]
Outcome = tuple[ItemKey, ItemResult | BaseException]

# Deterministic failures of an item's input (a corrupt bag, a missing transform, an unknown
# schema version, a bad value): m3gd raises them as `DataError`, and retrying cannot help.
# Anything else (OSError, MemoryError, a killed worker, a library's ValueError such as zarr's
# ContainsGroupError in a race) may be transient and is retried.
PERMANENT_ERRORS: tuple[type[Exception], ...] = (DataError,)


class _Permanent:
    """A permanent error carried back from a Dask worker as a value, so Dask does not retry."""

    def __init__(self, error: Exception) -> None:
        self.error = portable(error)


def portable(error: Exception) -> Exception:
    """`error` if it survives dask.distributed's serialization; else the same error without
    its cause chain and traceback (a library's exception in the chain may not pickle); else a
    DataError naming its type and message. The driver then prints the line `--local` prints."""
    from distributed.protocol.pickle import dumps, loads

    def survives(err: Exception) -> bool:
        try:
            loads(dumps(err))
        except Exception:
            return False
        return True

    if survives(error):
        return error
    error.__cause__ = error.__context__ = error.__traceback__ = None
    if survives(error):
        return error
    return DataError(f"{type(error).__name__}: {error}")


def limit_threads() -> None:
    """One BLAS/torch thread per worker process: 2-core machines stall otherwise."""
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover - torch is a dependency
        pass


@contextlib.contextmanager
def single_threaded() -> Iterator[None]:
    """Run the body with one BLAS/OpenMP thread and one torch thread, then restore.

    Every item runs like this under every executor (parallelism is across items), so
    outputs are bit-identical whichever executor ran them: a BLAS sgemm on 2 threads
    rounds differently from one on 1 thread (measured: the fpfh lift's float32 output
    changes, and float16 packets then differ by one ulp).
    """
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with threadpool_limits(limits=1):
            yield
    finally:
        torch.set_num_threads(before)


def run_item(fn: RunFn, cfg: M3GDConfig, item: Item) -> ItemResult:
    """One item, single-threaded (see `single_threaded`)."""
    with single_threaded():
        return fn(cfg, item)


def quiet_distributed() -> None:
    """Keep dask.distributed's INFO chatter (nannies, connections) out of normal output.

    distributed sets levels on its own child loggers when imported, so the parent's level
    set by the CLI does not reach them; only a debug run (-v) shows them.
    """
    level = logging.DEBUG if logging.getLogger().level <= logging.DEBUG else logging.WARNING
    for name in list(logging.root.manager.loggerDict):
        if name == "distributed" or name.startswith("distributed."):
            logging.getLogger(name).setLevel(level)


class LocalExecutor:
    """Runs items one after another in this process (for debugging: --local)."""

    dashboard_link: str | None = None

    def map(self, fn: RunFn, cfg: M3GDConfig, items: list[Item], retries: int,
            resources: dict[str, float] | None = None) -> Iterator[Outcome]:
        """Run every item, retrying failures, yielding outcomes in order (`resources` is a
        Dask notion: this process runs everything)."""
        for item in items:
            outcome: ItemResult | BaseException = RuntimeError(f"{item.key}: never ran")
            for attempt in range(retries + 1):
                try:
                    outcome = run_item(fn, cfg, item)
                    break
                except PERMANENT_ERRORS as err:
                    outcome = err
                    break
                except Exception as err:
                    outcome = err
                    log.warning("%s failed (attempt %d): %s", item.key, attempt + 1, err)
            yield item.key, outcome

    def close(self) -> None:
        """Nothing to release."""


class PinToCore(WorkerPlugin):
    """Dask worker plugin: pin LocalCluster worker `name` to core cpus[name % len(cpus)].

    Thread-count settings do not reach every library: open3d 0.20 runs normals and FPFH
    on TBB, which ignores OMP_NUM_THREADS and threadpoolctl and sizes itself from the
    process's CPU affinity (measured: FPFH used about two cores per worker, so 2 workers
    barely beat 1 on the packets stage; docs/benchmarks.md, 'Design measurements'). A
    one-core affinity mask, set before any TBB use, makes every library in the worker run
    on its own core.
    """

    name = "m3gd-pin-to-core"

    def __init__(self, cpus: list[int]) -> None:
        self.cpus = cpus

    def setup(self, worker: Any) -> None:
        """Pin this worker process (its name is its index in a LocalCluster)."""
        try:
            index = int(worker.name)
        except (TypeError, ValueError):
            return
        os.sched_setaffinity(0, {self.cpus[index % len(self.cpus)]})


HEARTBEAT_FAILED = "Failed to communicate with scheduler during heartbeat."
"""What distributed's worker logs, with a traceback, when its heartbeat's connection closes
under it: on shutdown, the worker's own close closes its connection pool while a heartbeat
is in flight (measured: once in three to six closes of a 2-worker LocalCluster, 2026-11-28)."""


class ClosingHeartbeatFilter(logging.Filter):
    """Drops `HEARTBEAT_FAILED` from the `distributed.worker` logger while its worker is
    closing; every other record, and that one from a running worker, passes."""

    def __init__(self, worker: Any) -> None:
        super().__init__()
        self.worker = worker

    def filter(self, record: logging.LogRecord) -> bool:
        """False for the heartbeat failure of a closing or closed worker."""
        from distributed.core import Status

        closing = self.worker.status in (Status.closing, Status.closed, Status.failed)
        return not (closing and record.getMessage() == HEARTBEAT_FAILED)


class QuietHeartbeatOnClose(WorkerPlugin):
    """Dask worker plugin: install `ClosingHeartbeatFilter` in each worker process."""

    name = "m3gd-quiet-heartbeat-on-close"

    def setup(self, worker: Any) -> None:
        """Filter this worker's heartbeat failure once it is closing."""
        logging.getLogger("distributed.worker").addFilter(ClosingHeartbeatFilter(worker))


class DaskExecutor:
    """Runs items on a dask.distributed cluster: a new LocalCluster or an existing one."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 dashboard: bool = False) -> None:
        from distributed import Client, LocalCluster

        quiet_distributed()
        self.cluster: Any = None
        if scheduler:
            self.client = Client(scheduler)
        else:
            n = workers or max(1, os.cpu_count() or 1)
            self.cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0" if dashboard else None,
                # the scheduler's HTTP routes (health, metrics) bind 8787 even without a
                # dashboard and warn when another cluster holds it: any free port instead
                scheduler_kwargs={"dashboard_address": ":0"},
                env={"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
            )
            self.client = Client(self.cluster)
            self.client.register_plugin(QuietHeartbeatOnClose())
            cpus = sorted(os.sched_getaffinity(0))
            if n <= len(cpus):  # a worker per core: pin each (restarted workers too)
                self.client.register_plugin(PinToCore(cpus))
        self.client.run(limit_threads)
        self.dashboard_link: str | None = self.client.dashboard_link if dashboard else None

    def map(self, fn: RunFn, cfg: M3GDConfig, items: list[Item], retries: int,
            resources: dict[str, float] | None = None) -> Iterator[Outcome]:
        """Run every item, at most one per worker thread at a time; yield outcomes as they end.

        `resources` (e.g. {"GPU": 1}): every item needs them, so it runs only on workers that
        declare them (`dask worker --resources GPU=1`, or a LocalCluster's `resources=`).

        Items are handed out greedily (the next one goes to the first free worker) instead
        of all being submitted at once: measured with 4 recordings' packets items on 2
        workers, up-front submission let the scheduler place 3 of them on one worker
        (docs/benchmarks.md, 'Design measurements').
        """
        from distributed import as_completed

        if not items:
            return
        tag = uuid.uuid4().hex[:8]
        pending = list(reversed(items))
        futures: dict[Any, ItemKey] = {}

        def submit() -> Any:
            item = pending.pop()
            fut = self.client.submit(_run_limited, fn, cfg, item, retries=retries, pure=False,
                                     key=f"{item.key.format()}-{tag}",
                                     resources=resources or None)
            futures[fut] = item.key
            return fut

        slots = max(1, sum(self.client.nthreads().values()))
        running = as_completed([submit() for _ in range(min(slots, len(pending)))])
        for fut in running:
            if pending:
                running.add(submit())
            key = futures.pop(fut)
            try:
                result = fut.result()
            except Exception as err:
                yield key, err
                continue
            yield key, result.error if isinstance(result, _Permanent) else result

    def close(self) -> None:
        """Shut down the client and the cluster this executor started."""
        # all work is done: a worker slow to exit is killed, which is no news to the user
        logging.getLogger("distributed.nanny").setLevel(logging.ERROR)
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _run_limited(fn: RunFn, cfg: M3GDConfig, item: Item) -> ItemResult | _Permanent:
    """Run one item in a worker with one compute thread; a data error comes back as a value."""
    limit_threads()
    try:
        return run_item(fn, cfg, item)
    except PERMANENT_ERRORS as err:
        return _Permanent(err)
