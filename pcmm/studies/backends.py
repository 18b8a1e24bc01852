"""Where the runs of a design study go: this process, a local process pool (spawned
workers, a bounded window of runs in flight), or a Dask distributed cluster.  Each
yields the rows as runs finish; stopping early stops the runs in flight."""
from __future__ import annotations

import itertools
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Iterable, Iterator

from ..errors import SimulationError, UsageError
from .job import Job, run_one


def _ignore_sigint() -> None:
    """Pool workers leave Ctrl-C to the sweep, which stops them: a run cut short by the
    user is not a result."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_serial(jobs: Iterable[Job]) -> Iterator[dict]:
    for job in jobs:
        yield run_one(job)


def run_pool(jobs: Iterable[Job], workers: int) -> Iterator[dict]:
    """A local process pool (spawned workers); a bounded window of runs in flight."""
    import multiprocessing
    from concurrent.futures.process import BrokenProcessPool
    ex = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_ignore_sigint)
    jobs = iter(jobs)
    pending: dict = {}
    try:
        while True:
            for job in itertools.islice(jobs, max(0, 4 * workers - len(pending))):
                pending[ex.submit(run_one, job)] = job
            if not pending:
                return
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                job = pending.pop(fut)
                try:
                    yield fut.result()
                except BrokenProcessPool:
                    raise SimulationError(f"a worker process died (killed, or crashed in native code) while "
                                          f"runs were in flight, e.g. run {job.index} ({job.values}); the runs "
                                          "that finished are kept, --resume runs the rest") from None
    finally:
        procs = list((getattr(ex, "_processes", None) or {}).values())
        ex.shutdown(wait=False, cancel_futures=True)
        for proc in procs:  # runs still in flight when the sweep stops early are stopped now
            if proc.is_alive():
                proc.terminate()


def _distributed():
    try:
        import distributed
    except ImportError:
        raise UsageError("--scheduler needs Dask's distributed package, which is not installed: "
                         "pip install 'pcmm[sweep]' (or run without --scheduler: a local process pool)") from None
    return distributed


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

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def run_dask(jobs: Iterable[Job], dask: DaskCluster) -> Iterator[dict]:
    """The runs on a Dask cluster, a bounded window of them in flight."""
    import distributed
    client = dask.client
    jobs = iter(jobs)
    pending: dict = {}
    queue = distributed.as_completed()
    try:
        def fill():
            for job in itertools.islice(jobs, max(0, 4 * dask.slots - len(pending))):
                fut = client.submit(run_one, job, pure=False)
                pending[fut] = job
                queue.add(fut)
        fill()
        for fut in queue:
            job = pending.pop(fut)
            try:
                row = fut.result()
            except Exception as exc:  # the cluster lost the run (a worker died): stop, keep what finished
                raise SimulationError(f"run {job.index} ({job.values}) was lost by the Dask cluster "
                                      f"({type(exc).__name__}: {exc}); the runs that finished are kept, "
                                      "--resume runs the rest") from None
            yield row
            fill()
    finally:
        for fut in pending:
            fut.cancel()
