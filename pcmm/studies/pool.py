"""A local pool of worker processes that isolates every run of a study.

Each worker is a fresh Python process (``subprocess``, not ``multiprocessing``: no resource
tracker, no shared semaphores) that takes one run at a time over a pipe and keeps its caches
(the parsed scene, the Pinocchio models) for all the runs it is given.

* **A run that kills its worker** (a native crash, an out-of-memory kill) is a row with status
  ``crashed`` and the signal or exit code; the worker is replaced and the study goes on.
* **A run that outlives the time limit** is stopped (its worker killed and replaced) and is a
  row with status ``timeout``.
* **Short runs are queued two deep**: once the runs are seen to be short (the last one took less
  than :data:`QUEUE_BELOW` seconds), each worker is handed its next run before it finishes the one
  it runs, so that it never waits for the study's process to read its row and hand it the next (on
  a loaded machine, a wait for the CPU).  A queued run's time limit counts from when the study
  read the row before it (never earlier than the run started); a run queued behind one that
  crashed or timed out goes to another worker, fresh.  Long runs are handed one at a time (no
  run waits behind a long one while another worker is idle).
* **Workers die with their parent**: on Linux each asks the kernel for SIGKILL when the
  process that started it dies (``prctl(PR_SET_PDEATHSIG)``); elsewhere a watcher thread
  exits when the parent is gone.  ``kill -9`` of a study leaves no worker behind.
"""
from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection, wait
from typing import Callable, Iterable, Iterator

from ..errors import SimulationError

#: the per-run time limit when none is given, s (``--run-timeout``)
DEFAULT_RUN_TIMEOUT = 600.0
#: runs are queued two deep in each worker while the last run took less than this, s
QUEUE_BELOW = 1.0


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


def death_message(code: int | None) -> str:
    """Why a worker process ended, in words, from its exit status."""
    if code is None:
        return "the worker process running it stopped answering"
    if code < 0:
        name = _signal_name(code)
        why = {"SIGKILL": "killed: out of memory, or by another process",
               "SIGSEGV": "a crash in native code", "SIGABRT": "aborted: a crash in native code",
               "SIGBUS": "a crash in native code", "SIGFPE": "a crash in native code"}.get(name, "killed")
        return f"the worker process running it died of {name} ({why})"
    return f"the worker process running it exited with status {code}"


class _Worker:
    def __init__(self, init: str | None):
        to_child_r, to_child_w = os.pipe()
        from_child_r, from_child_w = os.pipe()
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)  # what this process imports, the worker does
        code = "from pcmm.studies.pool import worker_main; worker_main()"
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", code, str(to_child_r), str(from_child_w), str(os.getpid()), init or ""],
                pass_fds=(to_child_r, from_child_w), env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
        finally:
            os.close(to_child_r)
            os.close(from_child_w)
        self.send_conn = Connection(to_child_w, readable=False)
        self.recv_conn = Connection(from_child_r, writable=False)
        self.queue: list = []  # the jobs handed to it, in order: the first is the one it runs
        self.started = 0.0  # when the first of the queue started (or the row before it was read)

    @property
    def job(self):
        """The job it runs."""
        return self.queue[0]

    def give(self, fn, job) -> None:
        if not self.queue:
            self.started = time.monotonic()
        self.queue.append(job)
        self.send_conn.send((fn, job))

    def answered(self) -> None:
        """The row of the job it ran was read: it runs the next in its queue (from now, at the latest)."""
        self.queue.pop(0)
        self.started = time.monotonic()

    def kill(self) -> int | None:
        try:
            self.proc.kill()
        except OSError:
            pass
        try:
            return self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            return None
        finally:
            self.close()

    def close(self) -> None:
        for c in (self.send_conn, self.recv_conn):
            try:
                c.close()
            except OSError:
                pass


class WorkerPool:
    """``workers`` worker processes kept for the length of a study (an optimisation hands them
    batch after batch).  A job whose worker dies gives ``on_failure(job, "crashed", message,
    seconds)``, one that runs longer than ``timeout`` seconds ``on_failure(job, "timeout", ...)``;
    ``init`` (``"module:function"``) is called in each worker when it starts."""

    def __init__(self, workers: int, timeout: float | None, on_failure: Callable[[object, str, str, float], dict],
                 init: str | None = None):
        self.timeout, self.on_failure, self.init = timeout, on_failure, init
        self.pool: list[_Worker] = []
        self.starting: dict = {}  # recv_conn -> worker not ready yet
        try:
            for _ in range(workers):
                self._start()
        except BaseException:
            self.close(kill=True)
            raise

    def _start(self, dead: _Worker | None = None) -> None:
        w = _Worker(self.init)
        if dead is None:
            self.pool.append(w)
        else:
            self.pool[self.pool.index(dead)] = w
        self.starting[w.recv_conn] = w

    def imap(self, fn: Callable, jobs: Iterable) -> Iterator:
        """``fn(job)`` for every job, yielded as each finishes.  Stopping early (an error, Ctrl-C)
        kills the pool: the runs in flight are not results."""
        from collections import deque
        jobs = iter(jobs)
        again: deque = deque()  # jobs that were queued behind a run that crashed or timed out
        exhausted = False
        timeout, starting = self.timeout, self.starting
        depth = 1  # jobs per worker: 2 once a run was seen to take less than QUEUE_BELOW s

        def next_job():
            nonlocal exhausted
            if again:
                return again.popleft()
            if exhausted:
                return None
            job = next(jobs, None)
            exhausted = job is None
            return job

        def lost(w: _Worker, status: str, message: str, seconds: float) -> dict:
            """The row of the run a dead worker ran; the jobs queued behind it go again; a new worker."""
            row = self.on_failure(w.queue[0], status, message, seconds)
            again.extend(w.queue[1:])
            w.queue = []
            self._start(w)
            return row

        ok = False
        try:
            while True:
                for w in self.pool:
                    while w.recv_conn not in starting and len(w.queue) < depth:
                        job = next_job()
                        if job is None:
                            break
                        w.give(fn, job)
                busy = {w.recv_conn: w for w in self.pool if w.queue}
                if not busy and not again and (exhausted or not starting):
                    ok = True
                    return
                wait_for = None
                if timeout is not None and busy:
                    wait_for = max(0.0, min(w.started + timeout for w in busy.values()) - time.monotonic())
                for conn in wait([*busy, *starting], timeout=wait_for):
                    if conn in starting:
                        w = starting.pop(conn)
                        try:
                            conn.recv()
                        except (EOFError, OSError, pickle.UnpicklingError):
                            code = w.kill()
                            raise SimulationError(f"a worker process of the study could not start: "
                                                  f"{death_message(code).replace('running it ', '')}") from None
                        continue
                    w = busy[conn]
                    try:
                        row = conn.recv()
                    except (EOFError, OSError, pickle.UnpicklingError):
                        code = w.kill()
                        row = lost(w, "crashed", death_message(code), time.monotonic() - w.started)
                    else:
                        took = time.monotonic() - w.started
                        depth = 2 if took < QUEUE_BELOW else 1
                        w.answered()
                    yield row
                if timeout is not None:
                    now = time.monotonic()
                    for w in [w for w in self.pool if w.queue and now - w.started >= timeout]:
                        w.kill()
                        yield lost(w, "timeout", f"still running after the time limit of {timeout:g} s "
                                   "(--run-timeout); stopped", now - w.started)
        finally:
            if not ok:
                self.close(kill=True)

    def close(self, kill: bool = False) -> None:
        """End the workers: when their pipe closes (done), or at once (``kill``)."""
        for w in self.pool:
            if kill:
                w.kill()
            else:
                w.close()
        if not kill:
            for w in self.pool:
                try:
                    w.proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    w.kill()
        self.pool, self.starting = [], {}


def run_isolated(fn: Callable, jobs: Iterable, workers: int, timeout: float | None,
                 on_failure: Callable[[object, str, str, float], dict], init: str | None = None) -> Iterator:
    """``fn(job)`` for every job on a :class:`WorkerPool` of its own, yielded as each finishes."""
    pool = WorkerPool(workers, timeout, on_failure, init)
    try:
        yield from pool.imap(fn, jobs)
    finally:
        pool.close(kill=False)


# ---- the worker's side -----------------------------------------------------------------------

def die_with_parent(parent: int) -> None:
    """Ask to be killed when ``parent`` dies: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux, a
    watcher thread elsewhere.  If the parent is already gone, exit now."""
    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            libc = ctypes.CDLL(None, use_errno=True)
            PR_SET_PDEATHSIG = 1
            armed = libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)
    if not armed:
        def watch():
            while os.getppid() == parent:
                time.sleep(0.5)
            os._exit(1)
        threading.Thread(target=watch, daemon=True).start()


def worker_main() -> None:
    rfd, wfd, parent, init = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the study's to handle: it stops the workers
    if init:
        import importlib
        module, _, name = init.partition(":")
        getattr(importlib.import_module(module), name)()
    recv, send = Connection(rfd, writable=False), Connection(wfd, readable=False)
    import pcmm.run.loop  # noqa: F401  the run's own imports (Pinocchio, scipy) before the first time limit
    try:
        send.send("ready")
    except OSError:  # the study ended before this worker was needed
        return
    while True:
        try:
            fn, job = recv.recv()
        except (EOFError, OSError):
            return
        send.send(fn(job))
