"""Checks shared by the numerical-extremes and fuzz suites: every number finite, no hang.

The models these suites run are built by :mod:`builders` (``builders.ball``,
``builders.parallelogram``, ...).
"""
from __future__ import annotations

import contextlib
import math
import signal

import numpy as np
import pytest

TRAJECTORY_ARRAYS = ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


def numbers(obj):
    """Every number inside nested dicts / lists (bools and strings skipped)."""
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return
    if isinstance(obj, (int, float, np.floating, np.integer)):
        yield float(obj)
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from numbers(v)
    elif isinstance(obj, (list, tuple, np.ndarray)):
        for v in obj:
            yield from numbers(v)


def assert_finite(traj):
    """No NaN or inf in any array of any segment, nor in any event record."""
    assert traj.segments, "the trajectory has no samples"
    for k, s in enumerate(traj.segments):
        for name in TRAJECTORY_ARRAYS:
            arr = np.asarray(getattr(s, name), dtype=float)
            bad = ~np.isfinite(arr)
            assert not bad.any(), (f"segment {k} ({s.configuration}): {name} has {int(bad.sum())} non-finite "
                                   f"values, first at t = {s.t[np.argwhere(bad)[0][0]]:.9g} s")
    for ev in traj.events:
        assert all(math.isfinite(x) for x in numbers(ev)), f"event at t = {ev['t']}: non-finite number"


@contextlib.contextmanager
def deadline(seconds, what):
    """Fail (instead of hanging the suite) if the block runs longer than ``seconds``: a guard
    against hangs, never a speed check (the machines are shared: give minutes' worth of slack)."""
    class _Deadline(BaseException):
        pass

    def handler(signum, frame):
        raise _Deadline()
    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    except _Deadline:
        pytest.fail(f"{what}: still running after {seconds} s (a hang)")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def default_signals() -> None:
    """``preexec_fn`` of a child the suite will signal: SIGINT, SIGTERM and SIGHUP at their
    default dispositions.  A process started with a signal ignored keeps it ignored (pcmm honours
    ``nohup`` and a shell's background jobs, :mod:`pcmm.signals`), and the suite itself may be
    run so (``nohup``, ``cmd &`` in a script: SIGINT ignored), which its children would inherit."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)
