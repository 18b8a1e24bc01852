"""Hooks run in the suite's child processes as they start: in a study's worker processes
(``sweep(..., worker_init="study_hooks:NAME")``) faults a run can suffer there, and a count of the
Pinocchio models a worker builds; in a ``pcmm`` command started by :mod:`processes`, handshakes
with the test (a study that waits at a gate, a run that says it has begun)."""
import os
import time


#: how long a tau1 = 5.0 run of :func:`faulty` lasts, s
SLOW_S = 3.0
#: how long a tau1 = 4.0 run of :func:`faulty` hangs, s
HANG_S = 3600.0


def faulty():
    """tau1 = 3.0: the run aborts its worker (a native crash); tau1 = 4.0: the run hangs
    (:data:`HANG_S`); tau1 = 5.0: the run lasts :data:`SLOW_S` seconds, whatever the machine's
    speed: it runs, then waits out the rest (a wait before the run added the run's own time, which
    a loaded machine stretches past a time limit a test sets a little above SLOW_S)."""
    import pcmm.run.loop as loop
    real = loop.simulate

    def simulate(scene, options=None, progress=None):
        if scene.forces[0].value == 3.0:
            os.abort()
        if scene.forces[0].value == 4.0:
            time.sleep(HANG_S)
        if scene.forces[0].value == 5.0:
            end = time.monotonic() + SLOW_S
            try:
                return real(scene, options, progress)
            finally:
                time.sleep(max(0.0, end - time.monotonic()))
        return real(scene, options, progress)
    loop.simulate = simulate


def count_builds():
    """Append this worker's pid to $PCMM_TEST_BUILDS at each Pinocchio model build."""
    import pinocchio
    real = pinocchio.buildModelFromXML
    log = os.environ["PCMM_TEST_BUILDS"]

    def build(*args, **kw):
        with open(log, "a") as f:
            f.write(f"{os.getpid()}\n")
        return real(*args, **kw)
    pinocchio.buildModelFromXML = build


class FaultyPlugin:
    """A Dask worker plugin applying :func:`faulty` in every worker, restarted ones included."""

    def setup(self, worker):
        faulty()


def echo(job):
    """A run for :class:`pcmm.studies.pool.WorkerPool` tests: ``"abort"`` crashes the worker
    (after 0.5 s), ``"hang"`` hangs it (:data:`HANG_S`), anything else is its own row."""
    if job == "abort":
        time.sleep(0.5)
        os.abort()
    if job == "hang":
        time.sleep(HANG_S)
    return job


def hold_table():
    """In a study's own process (not its workers; see :mod:`processes`): right after its results
    table took the rows ``$PCMM_TEST_HOLD`` says (``ROWS:FOLDER``), write ``FOLDER/held`` with
    that count and wait until ``FOLDER/go`` exists (at most 10 minutes: never a hang).  A signal
    meanwhile is answered as anywhere in the study (the wait is a Python loop)."""
    from pathlib import Path
    import pcmm.studies.table as table
    rows, _, folder = os.environ["PCMM_TEST_HOLD"].partition(":")
    rows, folder = int(rows), Path(folder)
    real, count = table.ResultsTable.append, [0]

    def append(self, row):
        out = real(self, row)
        count[0] += 1
        if count[0] == rows:
            tmp = folder / "held.tmp"
            tmp.write_text(str(count[0]))
            tmp.replace(folder / "held")
            end = time.monotonic() + 600
            while not (folder / "go").exists() and time.monotonic() < end:
                time.sleep(0.005)
        return out
    table.ResultsTable.append = append


def mark_recorded():
    """In a ``pcmm run`` process (see :mod:`processes`): create the file ``$PCMM_TEST_MARK`` once
    the run has recorded its first segment (it has taken steps: a signal now stops the run itself)."""
    from pathlib import Path
    import pcmm.run.recording as recording
    marker, real = Path(os.environ["PCMM_TEST_MARK"]), recording.record_samples

    def record_samples(*args, **kwargs):
        out = real(*args, **kwargs)
        if not marker.exists():
            marker.touch()
        return out
    recording.record_samples = record_samples
