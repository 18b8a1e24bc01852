"""Where the runs of a design study go: this process, a local process pool (spawned
workers, a bounded window of runs in flight), or a Dask distributed cluster.  Each
yields the rows as runs finish; stopping early stops the runs in flight."""
from __future__ import annotations

import itertools
import time
import uuid
from typing import Iterable, Iterator

from ..errors import UsageError
from .job import Job, failed_row, run_one
from .pool import DEFAULT_RUN_TIMEOUT, run_isolated


def run_serial(jobs: Iterable[Job]) -> Iterator[dict]:
    """The runs in this process, one after the other (no isolation, no time limit)."""
    for job in jobs:
        yield run_one(job)


def run_pool(jobs: Iterable[Job], workers: int, run_timeout: float | None = DEFAULT_RUN_TIMEOUT,
             init: str | None = None) -> Iterator[dict]:
    """A local pool of worker processes (:mod:`pcmm.studies.pool`): a run that crashes its worker
    or outlives ``run_timeout`` is a row (``crashed``, ``timeout``) and the study goes on."""
    return run_isolated(run_one, jobs, workers, run_timeout, failed_row, init)


def _distributed():
    try:
        import distributed
    except ImportError:
        raise UsageError("--scheduler needs Dask's distributed package, which is not installed: "
                         "pip install 'pcmm[sweep]' (or run without --scheduler: a local process pool)") from None
    return distributed


def _warm_worker():
    """A Dask worker plugin: the run's imports (Pinocchio, scipy) when the worker starts, so that
    they are not counted in its first run's time limit."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class WarmWorker(WorkerPlugin):
        idempotent = True

        def setup(self, worker):
            import importlib
            importlib.import_module("pcmm.run.loop")
    return WarmWorker()


class DaskCluster:
    """A connection to a Dask distributed cluster: ``scheduler`` is its address, or ``local``
    to start a :class:`distributed.LocalCluster` of ``workers`` single-threaded processes.
    Connected at once, so an unreachable scheduler is reported before anything is written."""

    def __init__(self, scheduler: str, workers: int):
        distributed = _distributed()
        self.cluster = None
        try:
            if scheduler == "local":
                self.cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                        dashboard_address=None)
                self.client = distributed.Client(self.cluster)
            else:
                self.client = distributed.Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            if self.cluster is not None:
                self.cluster.close()
            raise UsageError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({exc})") from None
        self.slots = max(1, sum(self.client.nthreads().values()))
        register = getattr(self.client, "register_plugin", None) or self.client.register_worker_plugin
        register(_warm_worker(), name="pcmm-warm")  # every worker, restarted ones too, imports pcmm's run first

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _run_reporting_start(job: Job, topic: str) -> dict:
    """:func:`run_one` on a Dask worker, first telling the client that the run starts now (an
    event on ``topic`` naming the task): its time limit counts from here, not from when it was
    submitted (it may wait for a worker, or for a crashed one to be replaced)."""
    import distributed
    worker = distributed.get_worker()
    worker.log_event(topic, {"key": str(worker.get_current_task())})
    return run_one(job)


def run_dask(jobs: Iterable[Job], dask: DaskCluster, run_timeout: float | None = DEFAULT_RUN_TIMEOUT) -> Iterator[dict]:
    """The runs on a Dask cluster, about one per worker thread in flight.  A run the cluster
    loses (its worker died, and died again on the retries Dask allows) is a ``crashed`` row; a
    run still going ``run_timeout`` seconds after it started on its worker (a run that Dask
    starts again after losing its worker: after that start) is a ``timeout`` row, and its worker
    is restarted."""
    import distributed
    client = dask.client
    jobs = iter(jobs)
    pending: dict = {}  # future -> (job, submitted at)
    started: dict[str, float] = {}  # task key -> when its worker reported it started (this clock)
    topic = f"pcmm-run-started-{uuid.uuid4().hex}"

    def on_start(event) -> None:  # in the client's event-loop thread
        started[str(event[1]["key"])] = time.monotonic()
    client.subscribe_topic(topic, on_start)
    try:
        while True:
            for job in itertools.islice(jobs, max(0, dask.slots + 1 - len(pending))):
                pending[client.submit(_run_reporting_start, job, topic, pure=False)] = (job, time.monotonic())
            if not pending:
                return
            wait_for = None
            if run_timeout is not None:
                now = time.monotonic()
                # a run not started yet has its deadline run_timeout after its start, later than now + run_timeout
                deadlines = [started.get(str(f.key), now) + run_timeout for f in pending]
                wait_for = max(0.05, min(deadlines) - now)
            try:
                done = distributed.wait(list(pending), timeout=wait_for, return_when="FIRST_COMPLETED").done
            except (distributed.TimeoutError, TimeoutError):
                done = set()
            for fut in [f for f in pending if f in done]:
                job, t0 = pending.pop(fut)
                try:
                    row = fut.result()
                except Exception as exc:  # the cluster lost the run: its worker died (on every retry)
                    row = failed_row(job, "crashed", f"the Dask cluster lost the run ({type(exc).__name__}: "
                                     f"{exc}): its worker process died while running it", time.monotonic() - t0)
                started.pop(str(fut.key), None)
                yield row
            if run_timeout is not None:
                now = time.monotonic()
                for fut in [f for f in pending if now - started.get(str(f.key), now) >= run_timeout]:
                    job, _ = pending.pop(fut)
                    t_start = started.pop(str(fut.key))
                    _stop_on_cluster(client, fut)
                    yield failed_row(job, "timeout", f"still running after the time limit of {run_timeout:g} s "
                                     "(--run-timeout); stopped (its Dask worker restarted)", now - t_start)
    finally:
        for fut in pending:
            fut.cancel()
        try:
            client.unsubscribe_topic(topic)
        except Exception:  # the client is closing or closed: nothing is subscribed any more
            pass


def _stop_on_cluster(client, fut) -> None:
    """Cancel a run and restart the worker running it (a thread cannot be stopped otherwise)."""
    try:
        busy = [w for w, keys in client.processing().items() if fut.key in keys]
        fut.cancel()
        if busy:
            client.restart_workers(busy)
    except Exception:  # the cluster cannot do it (an old scheduler): the run is reported all the same
        pass


class Runner:
    """Where a study's runs go, kept open across batches: this process (``workers`` = 1), a
    :class:`~pcmm.studies.pool.WorkerPool`, or a Dask cluster (``scheduler``)."""

    def __init__(self, workers: int, scheduler: str | None = None, run_timeout: float | None = DEFAULT_RUN_TIMEOUT,
                 init: str | None = None):
        from .pool import WorkerPool
        self.run_timeout = run_timeout
        self.dask = DaskCluster(scheduler, workers) if scheduler else None
        self.pool = None
        if self.dask is None and workers > 1:
            self.pool = WorkerPool(workers, run_timeout, failed_row, init)
        self.slots = self.dask.slots if self.dask else workers

    def rows(self, jobs: Iterable[Job]) -> Iterator[dict]:
        if self.dask is not None:
            return run_dask(jobs, self.dask, self.run_timeout)
        if self.pool is not None:
            return self.pool.imap(run_one, jobs)
        return run_serial(jobs)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
        if self.dask is not None:
            self.dask.close()
