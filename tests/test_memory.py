"""A run's retained memory (issue 26, item 5): what each segment and event keeps after the run."""
from __future__ import annotations

import gc

import scipy.integrate._ode as scipy_ode

import builders
import pcmm


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
