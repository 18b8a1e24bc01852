"""Continuous contact-force laws: the alternative to the instantaneous impulse.

The paper's introduction weighs the impulse-momentum method (fast, no
collision process) against continuous contact-force models (the collision
process resolved, stiff, parameters hard to choose).  A ``stop`` transition may
pick a continuous law per transition (``law = "..."`` with ``stiffness`` and
``exponent``); the impact then becomes a contact phase: from the instant the
gap closes until it opens again, the normal force

    F = k delta^n (1 + D(e) delta' / v-),   F >= 0

acts between the contact points (delta: penetration, v-: the normal approach
speed at first contact).  The hysteresis damping ``D(e)`` is derived from the
restitution coefficient e by each law:

* Hunt and Crossley (1975):        D = 3 (1 - e) / 2
* Lankarani and Nikravesh (1990):  D = 3 (1 - e^2) / 4   (e close to 1)
* Flores et al. (2011):            D = 8 (1 - e) / (5 e) (any e > 0)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.configuration import Configuration
from .contact import contact_state
from ..scene.spec import StopSpec
from ..ode.witness import Guard

DAMPING = {
    "hunt_crossley": lambda e: 1.5 * (1.0 - e),
    "lankarani_nikravesh": lambda e: 0.75 * (1.0 - e * e),
    "flores": lambda e: 8.0 * (1.0 - e) / (5.0 * e),
}
LAWS = ("impulse",) + tuple(DAMPING)


def normal_force(law: str, k: float, n: float, e: float, delta: float, delta_dot: float, v_impact: float) -> float:
    """Normal contact force (N) for penetration ``delta`` and its rate."""
    if delta <= 0.0:
        return 0.0
    f = k * delta ** n * (1.0 + DAMPING[law](e) * delta_dot / v_impact)
    return f if f > 0.0 else 0.0


@dataclass
class ContactPhase:
    """One resolved collision: the stop's contact force acts until the gap reopens."""

    cfg: Configuration
    tr: StopSpec
    v_impact: float  # normal approach speed at first contact (> 0)
    t_start: float
    q_start: np.ndarray
    v_start: np.ndarray

    def force(self, q, v):
        """(F, generalized force J_n^T F) at (q, v)."""
        _, gap, vn, Jn = contact_state(self.cfg, q, v, self.tr.contact)
        F = normal_force(self.tr.law, self.tr.stiffness, self.tr.exponent, self.tr.restitution,
                         -gap, -vn, self.v_impact)
        return F, Jn * F

    def rhs(self):
        """Augmented right-hand side: the state plus the impulse integral of F
        (the contact force is evaluated once per call)."""
        coords = self.cfg.coords

        def f(t, yx):
            q, v = coords.unpack(t, yx[:-1])
            F, generalized = self.force(q, v)
            return np.append(coords.derivative(t, q, v, generalized), F)
        return f

    def end_guard(self):
        """Fires when the gap reopens (the bodies separate)."""
        unpack = self.cfg.coords.unpack

        def g(t, yx):
            q, v = unpack(t, yx[:-1])
            return contact_state(self.cfg, q, v, self.tr.contact)[1]
        return Guard(f"transition '{self.tr.name}': the contact reopens", g, +1, "separation", self.tr)
