"""Hooks run in a study's worker processes as they start (``sweep(..., worker_init="study_hooks:NAME")``):
faults a run can suffer there, and a count of the Pinocchio models a worker builds."""
import os
import time


#: how long a tau1 = 5.0 run of :func:`faulty` waits before it runs, s
SLOW_S = 3.0


def faulty():
    """tau1 = 3.0: the run aborts its worker (a native crash); tau1 = 4.0: the run hangs;
    tau1 = 5.0: the run waits :data:`SLOW_S` seconds, then runs."""
    import pcmm.run.loop as loop
    real = loop.simulate

    def simulate(scene, options=None, progress=None):
        if scene.forces[0].value == 3.0:
            os.abort()
        if scene.forces[0].value == 4.0:
            time.sleep(3600)
        if scene.forces[0].value == 5.0:
            time.sleep(SLOW_S)
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
    (after 0.5 s), ``"hang"`` hangs it, anything else is its own row."""
    if job == "abort":
        time.sleep(0.5)
        os.abort()
    if job == "hang":
        time.sleep(3600)
    return job
