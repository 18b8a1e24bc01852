"""A run's retained memory (issue 26, item 5): what each segment and event keeps after the run."""
from __future__ import annotations

import gc
import math
import tracemalloc
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.integrate._ode as scipy_ode

import builders
import pcmm
from pcmm.ode.integrators import INTEGRATORS


def _live_dop853_with_callbacks() -> int:
    return sum(1 for o in gc.get_objects() if isinstance(o, scipy_ode.dop853) and "solout" in vars(o))


def test_fortran_dop853_segments_leave_no_integrator_holding_their_steps(tmp_path):
    """scipy's ``ode`` keeps every DOP853 integrator alive (a reference the Fortran call takes to
    its bound call-back is never released); each one held its segment's call-backs and through
    them the stepper's steps and guards.  A ball with e = 1 bounces every 2 sqrt(2 h / g) =
    0.903 s from h = 1 m: 10 s is 11 impacts, 12 segments, and none may leave one behind."""
    path = builders.ball(tmp_path, 1.0, t_end=10.0, solver={"method": "DOP853F"})
    gc.collect()
    before = _live_dop853_with_callbacks()
    traj = pcmm.simulate(pcmm.load_scene(path))
    gc.collect()
    assert len(traj.events) == 11
    assert _live_dop853_with_callbacks() - before == 0


def test_segments_of_one_configuration_share_their_name_lists(tmp_path):
    """A bouncing ball has one segment per impact, all in 'free' (joint Y, links frame and ball,
    no force element, no constraint row): one copy of each name list per run, not per segment."""
    traj = pcmm.simulate(pcmm.load_scene(builders.ball(tmp_path, 1.0, t_end=3.0)))
    first, *rest = traj.segments
    assert len(rest) == 3  # impacts at 0.452, 1.355, 2.258 s
    assert (first.coordinates, first.links, first.force_names, first.constraint_labels) == (["Y"], ["frame", "ball"], [], [])
    for seg in rest:
        assert seg.coordinates is first.coordinates and seg.constraint_labels is first.constraint_labels


def _free_fall(t, y):
    """A height and its rate under gravity: y'' = -9.81."""
    return np.array([y[1], -9.81])


def test_fortran_dop853_retains_nothing_per_segment():
    """scipy's f2py wrapper of DOP853 keeps a reference to every call-back it is handed.  Handed
    each segment's closures (and ``ode``'s bound ``_solout``, which holds the integrator), every
    segment left ~0.57 kB behind (600 bounces of benchmarks/memory_events.py's ball, traced by
    line): a 1e6-impact run, 0.57 GB.  The Fortran code now gets the same two functions for the
    whole process.  Measured here on the integrator alone, Python-stepped (a free fall from 1 m
    to the floor, 0.452 s, its segment dropped each time): what 300 segments retain, per segment,
    must be far below the 0.57 kB (an empty object alone is 48 B; allow 64 B for the allocator's
    noise, 19 kB in all)."""
    method = INTEGRATORS["DOP853F"]
    opts = SimpleNamespace(rtol=1e-10, atol=1e-12, max_step=math.inf, step=1e-3, event_tol=1e-14, max_steps=10**6)
    t_floor = math.sqrt(2.0 / 9.81)

    def segment():
        seg = method.integrate(_free_fall, 0.0, np.array([1.0, 0.0]), t_floor, [], opts)
        assert abs(seg.y[0, -1]) < 1e-12 and seg.t[-1] == t_floor  # it reached the floor: y = 1 - g t^2 / 2

    for _ in range(20):  # warm-up: caches, the module's first use
        segment()
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        n = 300
        for _ in range(n):
            segment()
        gc.collect()
        per_segment = (tracemalloc.get_traced_memory()[0] - base) / n
    finally:
        tracemalloc.stop()
    assert per_segment < 64, f"{per_segment:.0f} B retained per segment"


@pytest.mark.slow  # a traced bouncing run (7.2 s)
def test_a_bouncing_run_holds_no_flight_for_its_audit_while_it_runs(tmp_path):
    """Each flight's energy audit (pcmm.run.audit) is measured when the flight ends, and what only
    the audit needed (its steps' dense outputs) is then dropped.  When the flights waited for
    their audit until the run ended, each held its steps, its reader and its stepping (~0.58 kB
    of the 1.26 kB per event a 1e5-bounce run grew by while it ran).  Measured inside one run of a
    ball with e = 1 (one flight per bounce, 0.903 s apart, from h = 1 m): the traced memory after
    60 and after 200 bounces, read by the progress call-back; what it grew by per bounce was
    632 B with the flights kept, 108 B without (the event table and the segment log's blocks)."""
    period = 2.0 * math.sqrt(2.0 / 9.81)
    path = builders.ball(tmp_path, 1.0, t_end=201.0 * period, solver={"max_events": 10**6})
    scene = pcmm.load_scene(path)
    pcmm.simulate(scene, pcmm.RunOptions(t_end=5.0 * period))  # warm-up: models, modules, caches
    marks, traced = (60, 200), {}

    def progress(t):
        for m in marks:
            if m not in traced and t >= (m + 0.25) * period:  # m bounces, at 0.5, 1.5, ... periods
                gc.collect()
                traced[m] = tracemalloc.get_traced_memory()[0]
    tracemalloc.start()
    try:
        traj = pcmm.simulate(scene, progress=progress)
    finally:
        tracemalloc.stop()
    assert len(traj.events) == 201 and traj.stats["macro_impacts"][0]["flights"] == 201
    per_bounce = (traced[200] - traced[60]) / (200 - 60)
    assert per_bounce < 400, f"{per_bounce:.0f} B per bounce while the run goes"
