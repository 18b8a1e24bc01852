"""Guards: the conditions that fire a configuration transformation.

A guard is a plain function ``g(t, y)`` of the integrator's state with the
attributes scipy's ``solve_ivp`` reads (``terminal``, ``direction``) plus the
transition it fires.  The event is located on the integrator's dense output.
Guard types form a registry; each builder takes (configuration, transition).
"""
from __future__ import annotations

from .configuration import Configuration
from .impulse import contact_state
from .scene import TransitionSpec


def _coordinate(cfg: Configuration, tr: TransitionSpec):
    row, offset = cfg.measure_row(tr.guard.measure)
    target = tr.guard.value - offset
    unpack = cfg.coords.unpack

    def g(t, y):
        q, _ = unpack(t, y)
        return row @ q - target
    return g


def _gap(cfg: Configuration, tr: TransitionSpec):
    unpack = cfg.coords.unpack

    def g(t, y):
        q, v = unpack(t, y)
        return contact_state(cfg, q, v, tr.contact)[1] - tr.guard.value
    return g


GUARD_BUILDERS = {"coordinate": _coordinate, "gap": _gap}


def make_guard(cfg: Configuration, tr: TransitionSpec):
    g = GUARD_BUILDERS[tr.guard.type](cfg, tr)
    g.terminal = True
    g.direction = tr.guard.direction
    g.transition = tr
    return g


def guard_value(cfg: Configuration, tr: TransitionSpec, t, q, v) -> float:
    """The guard's value at a full state (for reports and restart checks)."""
    return make_guard(cfg, tr)(t, cfg.coords.pack(t, q, v))
