"""Guards: the conditions that fire a configuration transformation.

A guard is a plain function ``g(t, y)`` of the integrator's state with the
attributes scipy's ``solve_ivp`` reads (``terminal``, ``direction``) plus the
transition it fires.  The event is located on the integrator's dense output.
Guard types form a registry; each builder takes (configuration, transition).
"""
from __future__ import annotations

import numpy as np

from .configuration import Configuration
from .constraints import constrained_accelerations
from .impulse import contact_row, contact_state, gap_rate
from .scene import TransitionSpec


def _coordinate(cfg: Configuration, tr: TransitionSpec):
    row, offset = cfg.measure_row(tr.guard.measure)
    target = tr.guard.value - offset
    unpack = cfg.coords.unpack

    def g(t, y):
        q, _ = unpack(t, y)
        return row @ q - target
    if not cfg.coords.constrained and not cfg.has_planar:
        nv = cfg.nv
        g.rate = lambda t, y, f: row @ y[nv:]  # q' = v, the second half of the state
    else:  # the full (q, v) of a loop, or a planar joint's q' from v
        g.rate = lambda t, y, f: row @ cfg.qdot(*unpack(t, y))
    g.rate_from_state = True  # the graze test needs no right-hand side for it
    return g


def _gap(cfg: Configuration, tr: TransitionSpec):
    unpack = cfg.coords.unpack

    def g(t, y):
        q, v = unpack(t, y)
        return contact_state(cfg, q, v, tr.contact)[1] - tr.guard.value
    g.rate = lambda t, y, f: gap_rate(cfg, *unpack(t, y), tr.contact)
    g.rate_from_state = True
    return g


GUARD_BUILDERS = {"coordinate": _coordinate, "gap": _gap}


def make_guard(cfg: Configuration, tr: TransitionSpec, start: tuple | None = None):
    """The guard of ``tr`` in ``cfg``; ``start = (t0, y0)`` restarts it after a bounce.

    Right after a bounce the guard sits at zero to round-off, and a loop's
    dependent coordinates (solved by Newton) may even put it a hair on the
    penetrated side, where the next crossing would go unseen.  The restarted
    guard is shifted by what the restart state penetrates plus the measure's
    round-off (a few ulp; the Newton tolerance in a loop), so it starts
    strictly on the separated side; it is the plain guard again once the bodies
    have separated by more than that round-off.  The shift stays at round-off
    level, so it feeds no measurable energy into the bounces.
    """
    raw = GUARD_BUILDERS[tr.guard.type](cfg, tr)
    direction = tr.guard.direction
    if start is None:
        g = raw
    else:
        # round-off of a measure: a few ulp, plus the Newton tolerance of a loop's coordinates
        tiny = 4 * np.finfo(float).eps * max(1.0, abs(tr.guard.value)) + cfg.coords.position_noise
        offset = direction * (max(0.0, direction * raw(*start)) + tiny)
        state = {"armed": False}

        def g(t, y):
            val = raw(t, y)
            if not state["armed"] and val * direction < -tiny:
                state["armed"] = True
            return val if state["armed"] else val - offset
        if hasattr(raw, "rate"):  # a constant shift leaves the rate alone
            g.rate = raw.rate
            g.rate_from_state = getattr(raw, "rate_from_state", False)
    g.terminal = True
    g.direction = direction
    g.transition = tr
    return g


def guard_value(cfg: Configuration, tr: TransitionSpec, t, q, v) -> float:
    """The guard's value at a full state (for reports and restart checks)."""
    return make_guard(cfg, tr)(t, cfg.coords.pack(t, q, v))


def holding_force(merged: Configuration, source: Configuration, tr: TransitionSpec, locked: dict, t, qm, vm):
    """Normal contact force (N; > 0 compressive) that keeps a stop-merge merged.

    The merged state is mapped back onto the source configuration (locked
    joints at their values, at rest relative to each other) and the source's
    dynamics are solved with the contact's normal row as an extra constraint.
    """
    qs, vs = np.zeros(source.nv), np.zeros(source.nv)
    for name in source.joint_names:
        sl = source.joint_slice[name]
        if name in merged.joint_slice:
            qs[sl], vs[sl] = qm[merged.joint_slice[name]], vm[merged.joint_slice[name]]
        else:
            qs[sl] = locked[name]
    Jc, bc = source.coords.rows(t, qs, vs)
    Jn, bn = contact_row(source, qs, vs, tr.contact)
    _, lam = constrained_accelerations(source, qs, vs, np.vstack([Jc, Jn]), np.append(bc, bn))
    return float(lam[-1])


def make_release_guard(merged: Configuration, source: Configuration, tr: TransitionSpec, locked: dict):
    """Fires when the contact force holding a stop-merge would turn tensile."""
    unpack = merged.coords.unpack

    def g(t, y):
        qm, vm = unpack(t, y)
        return holding_force(merged, source, tr, locked, t, qm, vm)
    g.terminal = True
    g.direction = -1
    g.transition = tr
    g.release = (source.name, locked)
    return g
