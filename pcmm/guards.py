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
from .impulse import contact_row, contact_state
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


REARM_BAND = 1e-12  # relative to max(1, |value|)


def make_guard(cfg: Configuration, tr: TransitionSpec, armed: bool = True):
    """The guard of ``tr`` in ``cfg``.

    Right after a bounce the guard sits at zero, where round-off (a loop's
    dependent coordinates are solved to ~1e-14) can fake a crossing.  An
    unarmed guard is shifted by a tiny band until it has moved that band away
    from zero in the separating direction; then it is the plain guard.  A
    grazing re-approach that never leaves the band still fires, at a
    penetration of the band (1e-12 relative).
    """
    raw = GUARD_BUILDERS[tr.guard.type](cfg, tr)
    direction = tr.guard.direction
    if armed:
        g = raw
    else:
        band = REARM_BAND * max(1.0, abs(tr.guard.value))
        state = {"armed": False}

        def g(t, y):
            val = raw(t, y)
            if not state["armed"] and val * direction < -band:
                state["armed"] = True
            return val if state["armed"] else val - direction * band
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
