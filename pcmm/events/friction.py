"""The impact law at one point with Coulomb friction: Routh's process (two-dimensional impulse).

A point contact has a normal row J_n and a tangential row J_t (t is the normal turned by
-90 degrees, t = (n_y, -n_x)).  With W_eff the cut system's effective inverse inertia (the
inverse of the paper's M_f, Eq. 25, :mod:`pcmm.events.impulse`), the contact's 2 x 2 Delassus
matrix is ``W = [J_t; J_n] W_eff [J_t; J_n]^T``: an impulse (P_t, P_n) on b changes the contact
velocity (v_t, v_n) by ``W (P_t, P_n)``.  For a single normal row and no friction this is the
paper's Eq. 29 denominator.

Routh's process (Routh 1877; Keller, J. Appl. Mech. 53, 1986; Stronge, *Impact Mechanics*, 2000)
follows the impact through the normal impulse p as a time-like variable.  Within a phase
everything is linear in p:

* slide with slip direction sigma = sign v_t: ``dP_t = -sigma mu dp``,
  ``d(v_t, v_n)/dp = (W_tn - sigma mu W_tt, W_nn - sigma mu W_nt)``;
* stick (v_t = 0, possible while mu >= |kappa|, kappa = -W_tn / W_tt the stick ratio):
  ``dP_t = kappa dp`` and ``d(v_t, v_n)/dp = (0, W_nn - W_nt^2 / W_tt)``.

A slip that stops continues in stick when mu >= |kappa| and reverses otherwise; a contact at rest
in slip that cannot stick starts slipping the way sign(W_tn).  Compression ends at v_n = 0; the
impact ends by Newton's kinematic law at v_n = -e v_n^- (the default), by Poisson's at
p = (1 + e) p_c, or by Stronge's energetic law when the restitution work is -e^2 times the
compression work.  The three coincide while the slip direction does not change.

The work of each part is exact per phase: ``W_n = integral v_n dp``, ``W_t = integral v_t dP_t``;
they sum to KE^+ - KE^-, and W_t <= 0.  ``friction = "stick"`` is mu = infinity, and the impulse
is Routh's process in that limit (:func:`stick_impulse`): the slip is stopped at p = 0+ by the
tangential impulse -v_t^- / W_tt, so friction dissipates v_t^-^2 / (2 W_tt), leaving the normal
velocity v_n1 = v_n^- - W_nt v_t^- / W_tt, and the point then sticks to the end of the impact, which
the law names: Newton's at v_n^+ = -e v_n^-, so P = W^-1 (-v_t^-, -(1 + e) v_n^-) (for a pin, e = 0:
the paper's Eq. 29 with J = [J_t; J_n]); Poisson's and Stronge's both at v_n^+ = -e v_n1, so
P = W^-1 (-v_t^-, -v_n^- - e v_n1), the limit of :func:`routh` as mu grows (a sweep of mu goes on
smoothly into "stick").  The laws agree where v_t^- = 0 or W_nt = 0 (then v_n1 = v_n^-) and where
e = 0.  (Not the proportional path's P_i (v_i^- + v_i^+) / 2 for the split, whose tangential part
can be negative, as if friction fed energy in.)  Where stopping the slip already separates the point
(v_n1 >= 0) there is no compression: Newton's stick impulse is still taken while it pushes
(P_n >= 0), with no split (:attr:`FrictionalImpulse.no_split` says why); Poisson's and Stronge's
are refused (:class:`AmbiguousImpact`): their limit is a slip stopped by a tangential impulse with
no normal one, which no finite mu gives.

**Painleve.**  A slide phase with ``dv_n/dp = W_nn - sigma mu W_nt <= 0`` means the normal impulse
does not separate the sliding contact: the rigid-body law has no unique answer (Genot and
Brogliato 1999).  :func:`routh` refuses it with :class:`AmbiguousImpact`.

The reference this module must reproduce is ``routh()`` of ``tests/reference_rod_friction.py``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

LAWS = ("newton", "poisson", "energetic")


class AmbiguousImpact(Exception):
    """The rigid-body impact law has no unique answer here (Painleve), or no answer at all."""


@dataclass(frozen=True)
class Phase:
    """One phase of Routh's process: ``mode`` "stick", "slide+" or "slide-" (slip direction),
    from normal impulse ``p_start`` to ``p_end``, ended by ``ends`` ("slip stops",
    "compression ends", "impact ends")."""

    mode: str
    p_start: float
    p_end: float
    ends: str


@dataclass(frozen=True)
class FrictionalImpulse:
    """The outcome of one frictional point impact, contact axes (t, n); on b."""

    P_t: float
    P_n: float
    slip_before: float  # v_t^-: b's point relative to a's along t
    slip_after: float
    vn_before: float
    vn_after: float
    work_normal: float | None  # J, integral v_n dP_n (<= 0 unless Newton's law creates energy); None: no_split
    work_tangential: float | None  # J, integral v_t dP_t (<= 0 always); None: no_split
    phases: tuple[Phase, ...]
    mu: float  # math.inf for "stick"
    law: str
    no_split: str | None = None  # why Routh's process gives no split of the works here (Newton's "stick" only)
    #: the 2 x 2 Delassus matrix W in (t, n) it was solved with, as (W_tt, W_tn, W_nn): what the
    #: event's law check (:func:`law_normal_velocity`) reads
    delassus: tuple[float, float, float] | None = field(default=None, compare=False)

    @property
    def P(self) -> np.ndarray:
        return np.array([self.P_t, self.P_n])

    @property
    def phase_text(self) -> str:
        """e.g. ``"slide+ -> stick"`` (consecutive phases of one mode merged)."""
        modes: list[str] = []
        for ph in self.phases:
            if not modes or modes[-1] != ph.mode:
                modes.append(ph.mode)
        return " -> ".join(modes)

    @property
    def slip_changed(self) -> bool:
        """The slip stopped or reversed during the impact (where Newton's law may create energy); with no
        slip (mu = infinity) a slip before the impact is stopped at once."""
        return len({ph.mode for ph in self.phases}) > 1 or (math.isinf(self.mu) and self.slip_before != 0.0)


def stick_ratio(W: np.ndarray) -> float:
    """|kappa| = |W_tn| / W_tt: the friction a contact needs to stay stuck while p grows."""
    return abs(W[0, 1]) / W[0, 0]


def _slopes(W, mode: str, mu: float):
    """(dv_t/dp, dv_n/dp, dP_t/dp) of a phase."""
    if mode == "stick":
        return 0.0, W[1, 1] - W[0, 1] ** 2 / W[0, 0], -W[0, 1] / W[0, 0]
    sigma = 1.0 if mode == "slide+" else -1.0
    return W[0, 1] - sigma * mu * W[0, 0], W[1, 1] - sigma * mu * W[1, 0], -sigma * mu


def painleve_text(W, mode: str, mu: float, slope: float) -> str:
    sigma = "+1" if mode == "slide+" else "-1"
    return (f"Painleve: at this posture and mu = {mu:g} the contact's normal speed does not grow with its "
            f"normal impulse while it slides (slip direction {sigma}: W_nn - sigma mu W_nt = {slope:.6g} <= 0, "
            f"with W_nn = {W[1, 1]:.6g}, W_nt = {W[1, 0]:.6g}); the rigid-body impact law has no unique answer "
            "(lower mu, or model the contact's compliance)")


def stuck_at_once(W: np.ndarray, vt: float, vn: float, e: float, law: str = "newton") -> FrictionalImpulse:
    """Routh's process with no slip (mu -> infinity): the slip is stopped at p = 0+ by the tangential
    impulse -v_t / W_tt (its work -v_t^2 / (2 W_tt), the limit of the slide phase's
    -mu v_t^2 / (2 (mu W_tt - sigma W_tn))), leaving the normal velocity v_n1 = v_n - W_nt v_t / W_tt;
    then the point sticks (dP_t = kappa dp, dv_n/dp = W_nn - W_nt^2 / W_tt) until compression ends and
    the impact ends by ``law``: Newton's at v_n = -e v_n^-, Poisson's at p = (1 + e) p_c and Stronge's
    (restitution work -e^2 times the compression's) both at v_n = -e v_n1 on this one stick phase.  The
    works are exact: v_n is linear in p.  Raises :class:`AmbiguousImpact` when stopping the slip
    already separates the point (v_n1 >= 0: no compression)."""
    if law not in LAWS:
        raise ValueError(f"restitution law {law!r}: one of {LAWS}")
    Pt1 = -vt / W[0, 0]
    vn1 = vn + W[1, 0] * Pt1
    if not vn1 < 0:
        raise AmbiguousImpact(f"stopping the slip (tangential impulse {Pt1:.6g} N s) leaves the point separating "
                              f"(normal velocity {vn1:.6g} m/s) before any compression")
    slope = W[1, 1] - W[0, 1] ** 2 / W[0, 0]
    p_c = -vn1 / slope
    vn_end = -e * vn if law == "newton" else -e * vn1
    p = (vn_end - vn1) / slope
    phases = [Phase("stick", 0.0, 0.0, "slip stops"), Phase("stick", 0.0, p_c, "compression ends")]
    if e != 0.0:
        phases.append(Phase("stick", p_c, p, "impact ends"))
    return FrictionalImpulse(float(Pt1 - W[0, 1] / W[0, 0] * p), float(p), vt, 0.0, vn, float(vn_end),
                             0.5 * (vn1 + vn_end) * p, -0.5 * vt * vt / W[0, 0], tuple(phases), math.inf, law)


def stick_impulse(W: np.ndarray, vt: float, vn: float, e: float, law: str = "newton") -> FrictionalImpulse:
    """No slip (``friction = "stick"``, mu = infinity): Routh's process in that limit (module text).

    Newton's law: P = W^-1 (-v_t^-, -(1 + e) v_n^-), the velocity after (0, -e v_n^-); refused
    (:class:`AmbiguousImpact`) where P_n < 0, a contact pulling.  Its works are those of
    :func:`stuck_at_once` where that process ends at P; where it does not (v_n1 >= 0), ``no_split``
    says why and the works are None.

    Poisson's and Stronge's laws: :func:`stuck_at_once` itself, P = W^-1 (-v_t^-, -v_n^- - e v_n1),
    the velocity after (0, -e v_n1); refused where v_n1 >= 0 (stopping the slip separates the point:
    no compression to restitute)."""
    if law not in LAWS:
        raise ValueError(f"restitution law {law!r}: one of {LAWS}")
    if law != "newton":
        vn1 = vn - W[1, 0] * vt / W[0, 0]
        if not vn1 < 0:
            raise AmbiguousImpact(
                f"with no slip and the {law} law, stopping the slip ({vt:.6g} m/s, by the tangential impulse "
                f"{-vt / W[0, 0]:.6g} N s) already moves the point away from the surface (normal velocity "
                f"{vn1:.6g} m/s >= 0, from {vn:.6g}) before any compression: Routh's process as mu grows ends "
                "with no normal impulse, the slip stopped by friction alone, which no contact gives; give the "
                "contact a finite friction mu (Routh's process, in which it slides)")
        return replace(stuck_at_once(W, vt, vn, e, law), delassus=_delassus(W))
    P = np.linalg.solve(W, np.array([-vt, -(1.0 + e) * vn]))
    if P[1] < -1e-12 * float(np.abs(P).max()):  # (-e v_n - v_n1) / (W_nn - W_nt^2 / W_tt): v_n1 > -e v_n
        vn1 = vn - W[1, 0] * vt / W[0, 0]
        raise AmbiguousImpact(
            f"with no slip the impact needs a pulling normal impulse (P_n = {P[1]:.6g} N s, P_t = {P[0]:.6g} N s), "
            f"which a contact cannot give: stopping the slip ({vt:.6g} m/s) already moves the point away from the "
            f"surface (normal velocity {vn1:.6g} m/s, above Newton's -e v_n^- = {-e * vn:.6g} m/s); give the contact "
            "a finite friction mu (Routh's process, in which it slides)")
    v1 = np.array([vt, vn]) + W @ P
    try:  # where v_n1 < 0 it ends at P (v_n1 + (W_nn - W_nt^2 / W_tt) P_n = -e v_n^-): its works are P's
        fr = stuck_at_once(W, vt, vn, e, law)
    except AmbiguousImpact as exc:
        return FrictionalImpulse(float(P[0]), float(P[1]), vt, float(v1[0]), vn, float(v1[1]), None, None,
                                 (Phase("stick", 0.0, float(P[1]), "impact ends"),), math.inf, law,
                                 f"Routh's process with no slip has no answer here: {exc}", _delassus(W))
    return FrictionalImpulse(float(P[0]), float(P[1]), vt, float(v1[0]), vn, float(v1[1]), fr.work_normal,
                             fr.work_tangential, fr.phases, math.inf, law, delassus=_delassus(W))


def _delassus(W: np.ndarray) -> tuple[float, float, float]:
    return float(W[0, 0]), float(W[0, 1]), float(W[1, 1])


def law_normal_velocity(fr: FrictionalImpulse, e: float) -> tuple[float, str] | None:
    """The normal velocity after the impact ``fr`` that its restitution law names in closed form, and
    the law's text: Newton's -e v_n^- (any mu: Routh's process ends there); with no slip (mu =
    infinity) Poisson's and Stronge's -e v_n1, v_n1 = v_n^- - W_nt v_t^- / W_tt from the Delassus
    matrix the impulse was solved with.  None where there is no closed form (Poisson's or Stronge's
    with a finite mu: the end depends on the phases) or no Delassus matrix at hand."""
    if fr.law == "newton":
        return -e * fr.vn_before, f"Newton's restitution law (Eq. 21), e = {e:g}"
    if not math.isinf(fr.mu) or fr.delassus is None:
        return None
    W_tt, W_tn, _ = fr.delassus
    vn1 = fr.vn_before - W_tn * fr.slip_before / W_tt
    name = "Poisson's" if fr.law == "poisson" else "Stronge's energetic"
    return -e * vn1, (f"{name} restitution law with no slip (Routh's process as mu -> infinity: -e v_n1, e = {e:g}, "
                      f"v_n1 = {vn1:.9g} m/s the normal velocity once the slip ({fr.slip_before:.9g} m/s) is stopped)")


def routh(W: np.ndarray, vt: float, vn: float, mu: float, e: float, law: str = "newton",
          tol: float = 1e-15) -> FrictionalImpulse:
    """Routh's process for one frictional point impact (module text): ``W`` the 2 x 2 Delassus matrix
    in (t, n), (vt, vn) the contact velocity before (vn < 0), ``mu`` Coulomb's coefficient (math.inf:
    no slip), ``e`` the restitution coefficient, ``law`` in :data:`LAWS`.  Raises
    :class:`AmbiguousImpact` on a Painleve phase or an impact that does not end."""
    if law not in LAWS:
        raise ValueError(f"restitution law {law!r}: one of {LAWS}")
    if not vn < 0:
        raise ValueError(f"the contact does not approach (v_n = {vn})")
    if math.isinf(mu):
        return stick_impulse(W, vt, vn, e, law)
    vn_minus, vt_minus = vn, vt
    kappa = abs(W[0, 1]) / W[0, 0]
    scale = max(abs(vt), abs(vn))

    def start(vt_now: float) -> str:
        if abs(vt_now) > tol * scale:
            return "slide+" if vt_now > 0 else "slide-"
        if mu >= kappa:
            return "stick"
        return "slide+" if W[0, 1] > 0 else "slide-"

    mode = start(vt)
    p = Pt = Wn = Wt = 0.0
    p_c = W_c = None
    phases: list[Phase] = []
    for _ in range(16):
        at, an, kt = _slopes(W, mode, mu)
        if mode != "stick" and an <= 0:
            raise AmbiguousImpact(painleve_text(W, mode, mu, an))
        sigma = 0.0 if mode == "stick" else (1.0 if mode == "slide+" else -1.0)
        cands = []
        if mode != "stick" and at * sigma < 0:
            cands.append((-vt / at, "slip stops"))
        if p_c is None:
            cands.append((-vn / an, "compression ends"))
        if law == "newton":
            cands.append(((-e * vn_minus - vn) / an, "impact ends"))
        elif law == "poisson" and p_c is not None:
            cands.append(((1 + e) * p_c - p, "impact ends"))
        elif law == "energetic" and p_c is not None:
            target = -e * e * W_c - (Wn - W_c)  # restitution work still to do
            cands.append(((-vn + math.sqrt(max(vn * vn + 2 * an * target, 0.0))) / an, "impact ends"))
        cands = [(d, w) for d, w in cands if d >= -tol * (abs(p) + 1e-300)]
        if not cands:
            raise AmbiguousImpact("the impact does not end (no phase of Routh's process reaches the end of "
                                  "restitution)")
        d, why = min(cands, key=lambda c: c[0])
        d = max(d, 0.0)
        Wn += vn * d + 0.5 * an * d * d  # exact: v_n linear in p within the phase
        Wt += kt * (vt * d + 0.5 * at * d * d)
        vt, vn, Pt, p = vt + at * d, vn + an * d, Pt + kt * d, p + d
        phases.append(Phase(mode, p - d, p, why))
        if why == "compression ends":
            vn, p_c, W_c = 0.0, p, Wn
            if law == "newton" and e == 0.0:
                break
            if law in ("poisson", "energetic") and e == 0.0:
                break
        elif why == "impact ends":
            break
        else:  # the slip stops: stick, or reverse
            vt = 0.0
            mode = start(0.0)
    else:
        raise AmbiguousImpact("Routh's process did not end within 16 phases")
    if mode == "stick":
        vt = 0.0
    return FrictionalImpulse(float(Pt), float(p), vt_minus, float(vt), vn_minus, float(vn), float(Wn), float(Wt),
                             tuple(phases), float(mu), law, delassus=_delassus(W))
