"""Independent reference: a slender rod striking a rough floor with one end (numpy only, no pcmm).

A rigid rod (mass m, length L, moment of inertia I about its centroid G, m L^2 / 12 when uniform)
meets the floor y = 0 with its end A, the rod at angle theta to the horizontal:
G = A + (L/2)(cos theta, sin theta).  Before the impact G moves with v- = (u, w) and the rod
turns with omega- (counter-clockwise).  At A the floor applies the impulse P = (P_t, P_n)
(tangent x, normal y).  References: Routh, "Dynamics of a System of Rigid Bodies" (1877, the
graphical method of impact with friction); Keller, "Impact with friction", J. Appl. Mech. 53
(1986); Stronge, "Impact Mechanics" (Cambridge 2000), ch. 4-5, and "Rigid body collisions with
friction", Proc. R. Soc. A 431 (1990); Brogliato, "Nonsmooth Mechanics" (3rd ed. 2016) on
Painleve; Genot & Brogliato, "New results on Painleve paradoxes", Eur. J. Mech. A 18 (1999).

Contact kinematics
------------------
v_A = v_G + omega z x (A - G) = (u + omega (L/2) sin theta, w - omega (L/2) cos theta).  An impulse
P at A changes v_G by P/m and omega by ((A - G) x P)/I, so the contact velocity changes by
Delta v_A = W P with the Delassus (inverse effective mass) matrix, k = m (L/2)^2 / I (3 for a
uniform rod), s = sin theta, c = cos theta:

    W = (1/m) [[1 + k s^2, -k s c], [-k s c, 1 + k c^2]],   det W = (1 + k) / m^2   (uniform: 4/m^2).

Newton's (kinematic) restitution and Coulomb friction, Routh's process
----------------------------------------------------------------------
The impact is followed through its normal impulse p = P_n as a time-like variable (Routh, Keller,
Stronge): the contact velocities are linear in p within each phase,

* slide (slip direction sigma = sign v_t):  dP_t = -sigma mu dp,
  d(v_t, v_n)/dp = (W_tn - sigma mu W_tt, W_nn - sigma mu W_nt);
* stick (v_t = 0, possible while |W_tn| / W_tt <= mu):  dP_t = kappa dp with kappa = -W_tn / W_tt,
  d(v_t, v_n)/dp = (0, W_nn - W_nt^2 / W_tt) = (0, 1 / (W^-1)_nn).

A slip that stops (v_t reaches 0) continues in stick when mu >= |kappa| (the "stick ratio"), and
otherwise reverses (sigma -> -sigma).  A slip that starts from v_t- = 0 goes the way
sign(W_tn) (the way the contact point would slip without friction) when mu < |kappa|.
Compression ends at v_n = 0 (normal impulse p_c, normal work W_c); the impact ends, by

* Newton (the issue's law): v_n = -e v_n-;
* Poisson: p = (1 + e) p_c;
* Stronge (energetic): the normal work in restitution is -e^2 W_c.

The three coincide when the slope dv_n/dp does not change during the impact (no slip change,
or no coupling W_nt = 0); they differ when slip stops or reverses during it.  With Newton's law
the kinetic energy can RISE when slip stops during the impact (the normal impulse needed to reach
-e v_n- after a change of slope can do more positive work in restitution than it absorbed in
compression: Kane & Levinson's double pendulum, Stronge 1991); Stronge's energetic law cannot
raise it (its normal work is (1 - e^2) W_c <= 0 and friction's is <= 0).  :data:`ENERGY_GAIN`
is such a case for the rod.

Closed forms (Newton's law)
---------------------------
* Stick outcome: the final contact velocity is (0, -e v_n-), so P_stick = W^-1 (-v_t-, -(1+e) v_n-).
* Slide outcome (slip sigma throughout): P_n = -(1+e) v_n- / (W_nn - sigma mu W_nt), P_t = -sigma mu P_n.
* The critical mu between them: the slide outcome ends exactly at v_t = 0 iff it is the stick
  outcome, i.e. at mu* = -sigma P_t,stick / P_n,stick (sigma the initial slip).  Routh's process
  ends sliding in the initial direction for mu < mu*, and otherwise stops slipping before the end
  (then sticks if mu >= |kappa|, reverses if not).  mu* <= 0: the normal impulse alone stops the
  slip (sigma W_tn < 0 and a small initial slip), whatever mu.  For a rod that falls in pure translation (u = 0, omega = 0,
  w = -v): v_t- = 0, and it sticks iff mu >= mu_c = |kappa| = 3 s c / (1 + 3 s^2) (uniform rod),
  independent of e and v; P_stick = (m/4)(1+e) v (3 s c, 1 + 3 s^2).
* Energy: Delta KE = W_n + W_t with W_n = integral v_n dP_n, W_t = integral v_t dP_t (exact per phase).

Routh's process against the algebraic (one-shot) Newton-Coulomb problem that a simultaneous-contact
LCP solves: they give the same impulse when the slip does not change during the impact, and when
it stops and then sticks (the final contact velocity (0, -e v_n-) fixes P).  They differ when the
slip stops and reverses (mu < |kappa|): the algebraic problem then answers a full reversed slide
or even "stick" (when mu* <= mu < |kappa|, although the contact cannot stay stuck: keeping it stuck
needs |kappa| > mu), where Routh's process gives an impulse strictly inside the cone.

Painleve
--------
In a slide phase, dv_n/dp = W_nn - sigma mu W_nt; for the rod (sigma = -1: A slips away from the
side of G) that is (1 + 3 c^2 - 3 mu s c)/m, which is <= 0 when mu >= (1 + 3 c^2) / (3 s c)
(:func:`painleve_threshold`, smallest value 4/3 at tan theta = 2).  Then the normal impulse does not
separate the contact while it slides: the rigid-body problem is ambiguous or inconsistent.
* At the force level (a rod sliding on the floor): the normal acceleration is a_n = b + K lambda
  with K = W_nn - sigma mu W_nt < 0; with b > 0 both lambda = 0 and lambda = -b/K solve the LCP,
  with b < 0 none does (:func:`sliding_contact_forces`).
* At the impulse level: a rod sliding in contact (v_n- = 0) admits both P = 0 and a sticking
  impulse (an "impact without collision", Genot & Brogliato 1999): :func:`newton_lcp_solutions`
  lists every solution of the algebraic Newton-Coulomb complementarity problem.
Detection: any slide phase (or candidate sliding solution) with W_nn - sigma mu W_nt <= 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Rod:
    m: float = 1.0
    L: float = 1.0
    I: float | None = None  # about the centroid; None: uniform, m L^2 / 12

    @property
    def inertia(self) -> float:
        return self.m * self.L ** 2 / 12 if self.I is None else self.I

    def offset(self, theta):
        """A - G (world)."""
        return -0.5 * self.L * np.array([math.cos(theta), math.sin(theta)])

    def delassus(self, theta) -> np.ndarray:
        """W of the contact at A, (t, n) = (x, y) axes."""
        r = self.offset(theta)
        # Delta v_A = P/m + (r x P)/I z x r ; z x r = (-r_y, r_x); r x P = r_x P_y - r_y P_x
        Z = np.array([-r[1], r[0]])
        return np.eye(2) / self.m + np.outer(Z, Z) / self.inertia

    def contact_velocity(self, theta, vG, omega) -> np.ndarray:
        r = self.offset(theta)
        return np.asarray(vG, float) + omega * np.array([-r[1], r[0]])

    def apply(self, theta, vG, omega, P):
        """Body velocities after the impulse P at A."""
        r = self.offset(theta)
        return np.asarray(vG, float) + np.asarray(P) / self.m, omega + (r[0] * P[1] - r[1] * P[0]) / self.inertia

    def kinetic_energy(self, vG, omega) -> float:
        vG = np.asarray(vG, float)
        return 0.5 * self.m * vG @ vG + 0.5 * self.inertia * omega ** 2


@dataclass
class Phase:
    kind: str  # "slide" or "stick"
    sigma: int  # slip direction while sliding (0 in stick)
    p0: float  # normal impulse at its start
    p1: float  # at its end
    why_end: str  # "slip stops", "compression ends", "impact ends"


@dataclass
class Outcome:
    P: np.ndarray  # (P_t, P_n) on the rod at A
    v_contact_before: np.ndarray
    v_contact_after: np.ndarray
    vG_after: np.ndarray
    omega_after: float
    W_n: float  # normal work (<= 0 unless Newton's law creates energy)
    W_t: float  # tangential (friction) work, <= 0
    p_compression: float  # normal impulse at the end of compression
    W_compression: float  # normal work in compression
    phases: list = field(default_factory=list)
    painleve: bool = False  # a slide phase with dv_n/dp <= 0 occurred

    @property
    def final(self) -> str:
        return self.phases[-1].kind

    @property
    def energy_change(self) -> float:
        return self.W_n + self.W_t


def _slopes(W, kind, sigma, mu):
    """(dv_t/dp, dv_n/dp, dP_t/dp) of a phase."""
    if kind == "stick":
        k = -W[0, 1] / W[0, 0]
        return 0.0, W[1, 1] - W[0, 1] ** 2 / W[0, 0], k
    return W[0, 1] - sigma * mu * W[0, 0], W[1, 1] - sigma * mu * W[1, 0], -sigma * mu


def routh(rod: Rod, theta, vG, omega, mu, e, law="newton", tol=1e-15) -> Outcome:
    """Routh's incremental process for one frictional point impact (see the module text);
    ``law`` in {"newton", "poisson", "energetic"} picks how the impact ends."""
    W = rod.delassus(theta)
    v0 = rod.contact_velocity(theta, vG, omega)
    vt, vn = float(v0[0]), float(v0[1])
    if vn >= 0:
        raise ValueError(f"the contact does not approach (v_n- = {vn})")
    vn_minus = vn
    kappa = -W[0, 1] / W[0, 0]
    scale = max(abs(vt), abs(vn), 1e-300)

    def start_phase(vt_now):
        if abs(vt_now) > tol * scale:
            return "slide", int(np.sign(vt_now))
        if mu >= abs(kappa):
            return "stick", 0
        return "slide", int(np.sign(W[0, 1]))

    kind, sigma = start_phase(vt)
    p, Pt, Wn, Wt = 0.0, 0.0, 0.0, 0.0
    p_c, W_c = None, None
    phases, painleve = [], False
    for _ in range(16):
        at, an, kt = _slopes(W, kind, sigma, mu)
        if kind == "slide" and an <= 0:
            painleve = True
        cands = []
        if kind == "slide" and at * sigma < 0:
            cands.append((-vt / at, "slip stops"))
        if p_c is None and an > 0:
            cands.append((-vn / an, "compression ends"))
        if law == "newton" and an > 0:
            cands.append(((-e * vn_minus - vn) / an, "impact ends"))
        elif law == "poisson" and p_c is not None:
            cands.append(((1 + e) * p_c - p, "impact ends"))
        elif law == "energetic" and p_c is not None and an > 0:
            # restitution work so far: Wn - W_c; reach -e^2 W_c: an/2 d^2 + vn d = target
            target = -e * e * W_c - (Wn - W_c)
            cands.append(((-vn + math.sqrt(vn * vn + 2 * an * target)) / an, "impact ends"))
        cands = [(d, w) for d, w in cands if d >= -tol * (abs(p) + 1e-300)]
        if not cands:
            raise RuntimeError("the impact does not end: a Painleve jam with slip that never stops"
                               if painleve else "the impact does not end")
        d, why = min(cands, key=lambda c: c[0])
        d = max(d, 0.0)
        # exact integrals over the phase (linear in p)
        Wn += vn * d + 0.5 * an * d * d
        Wt += kt * (vt * d + 0.5 * at * d * d)
        vt, vn, Pt, p = vt + at * d, vn + an * d, Pt + kt * d, p + d
        phases.append(Phase(kind, sigma, p - d, p, why))
        if why == "compression ends":
            vn, p_c, W_c = 0.0, p, Wn
        if why == "impact ends":
            break
        if why == "slip stops":
            vt = 0.0
            kind, sigma = start_phase(0.0)
        # "compression ends": same phase goes on into restitution (e = 0 with Newton ends here too)
        if law == "newton" and why == "compression ends" and e == 0.0:
            break
    else:
        raise RuntimeError("too many phases")
    P = np.array([Pt, p])
    vG1, w1 = rod.apply(theta, vG, omega, P)
    return Outcome(P, v0, rod.contact_velocity(theta, vG1, w1), vG1, w1, Wn, Wt, p_c, W_c, phases, painleve)


# ---- closed forms (Newton's law) -----------------------------------------------------------------
def stick_impulse(rod: Rod, theta, vG, omega, e) -> np.ndarray:
    """P_stick = W^-1 (-v_t-, -(1+e) v_n-): the impulse that leaves (0, -e v_n-)."""
    v0 = rod.contact_velocity(theta, vG, omega)
    return np.linalg.solve(rod.delassus(theta), np.array([-v0[0], -(1 + e) * v0[1]]))


def slide_impulse(rod: Rod, theta, vG, omega, mu, e, sigma) -> np.ndarray:
    """P for slip sigma throughout: P_n = -(1+e) v_n- / (W_nn - sigma mu W_nt), P_t = -sigma mu P_n."""
    W = rod.delassus(theta)
    vn = rod.contact_velocity(theta, vG, omega)[1]
    Pn = -(1 + e) * vn / (W[1, 1] - sigma * mu * W[1, 0])
    return np.array([-sigma * mu * Pn, Pn])


def critical_mu(rod: Rod, theta, vG, omega, e) -> float:
    """The mu that separates "slides to the end in its initial direction" (mu below it) from
    "slip stops during the impact" (mu above it), Newton's law.

    * Initial slip sigma != 0: rho = -sigma P_t,stick / P_n,stick (signed).  At mu = rho the
      slide-throughout impulse ends exactly at v_t = 0, i.e. it IS the stick impulse.  rho <= 0
      means the normal impulse's coupling alone stops the slip: it stops for every mu >= 0.
    * No initial slip: |kappa| (:func:`stick_ratio`), the same as |P_t,stick| / P_n,stick there.

    Once the slip has stopped the contact sticks if mu >= |kappa| and reverses otherwise."""
    v0 = rod.contact_velocity(theta, vG, omega)
    P = stick_impulse(rod, theta, vG, omega, e)
    sigma = np.sign(v0[0])
    if sigma == 0:
        return abs(P[0]) / P[1]
    return float(-sigma * P[0] / P[1])


def stick_ratio(rod: Rod, theta) -> float:
    """|kappa| = |W_tn| / W_tt: the friction a contact at rest in slip needs to stay stuck;
    3 s c / (1 + 3 s^2) for a uniform rod (the critical mu of a rod falling in translation)."""
    W = rod.delassus(theta)
    return abs(W[0, 1]) / W[0, 0]


def painleve_threshold(rod: Rod, theta) -> float:
    """The mu above which a slide with sigma = -sign(W_nt) has dv_n/dp <= 0:
    W_nn / |W_nt| = (1 + 3 c^2) / (3 s c) for a uniform rod (inf when W_nt = 0)."""
    W = rod.delassus(theta)
    return math.inf if W[1, 0] == 0 else W[1, 1] / abs(W[1, 0])


def newton_lcp_solutions(rod: Rod, theta, vG, omega, mu, e, tol=1e-12):
    """Every solution of the ALGEBRAIC Newton-Coulomb impact problem at A (the one-shot
    complementarity problem a simultaneous-contact LCP poses):
    P_n >= 0, v_n+ + e v_n- >= 0, P_n (v_n+ + e v_n-) = 0; |P_t| <= mu P_n, and P_t = -mu P_n
    sign(v_t+) when v_t+ != 0.  Enumerated by cases: no impulse, stick, slide +1, slide -1.
    Returns a list of (case, P)."""
    W = rod.delassus(theta)
    v0 = rod.contact_velocity(theta, vG, omega)
    out = []
    sc = max(1.0, float(np.abs(v0).max()))
    if v0[1] >= -tol * sc:  # no impulse is admissible when the contact does not approach
        out.append(("none", np.zeros(2)))
    P = np.linalg.solve(W, np.array([-v0[0], -(1 + e) * v0[1]]))
    if P[1] > tol * sc and abs(P[0]) <= mu * P[1] * (1 + 1e-12):
        out.append(("stick", P))
    for sigma in (1, -1):
        K = W[1, 1] - sigma * mu * W[1, 0]
        if abs(K) < 1e-300:
            continue
        Pn = -(1 + e) * v0[1] / K
        if Pn <= tol * sc:
            continue
        Pv = np.array([-sigma * mu * Pn, Pn])
        vt1 = v0[0] + (W @ Pv)[0]
        if sigma * vt1 > tol * sc:
            out.append((f"slide {sigma:+d}", Pv))
    return out


def sliding_contact_forces(rod: Rod, theta, omega, vt, mu, g=9.81):
    """The force-level problem of a rod sliding on the floor (A on it, v_n = 0, slip vt != 0):
    normal acceleration a_n = b + K lambda >= 0, lambda >= 0, complementary, with
    b = -g + omega^2 (L/2) sin theta (gravity and the centripetal acceleration of A) and
    K = W_nn - sigma mu W_nt.  Returns (K, b, [solutions lambda]): none (inconsistent) or two
    (ambiguous) solutions when K < 0, the Painleve paradox."""
    W = rod.delassus(theta)
    sigma = int(np.sign(vt))
    K = W[1, 1] - sigma * mu * W[1, 0]
    b = -g + omega ** 2 * 0.5 * rod.L * math.sin(theta)
    sols = []
    if b >= 0:
        sols.append(0.0)
    if K != 0 and -b / K > 0:
        sols.append(-b / K)
    return K, b, sols


# ---- worked cases ------------------------------------------------------------------------------------
UNIFORM = Rod(m=1.0, L=1.0)
#: Newton's law with e = 1 raising the kinetic energy: slip (towards G's side) stops during the
#: impact and the contact sticks; Stronge's energetic law on the same data loses energy.
ENERGY_GAIN = dict(theta=math.pi / 4, vG=(0.1, -1.0), omega=0.0, mu=0.9, e=1.0)
#: Painleve: tan theta = 2 (the threshold's minimum 4/3), mu = 1.5, A slipping away from G's side
#: (v_t < 0) while in contact (v_n- = 0): P = 0 and a sticking impulse both solve the impact problem.
PAINLEVE = dict(theta=math.atan(2.0), vG=(-1.0, 0.0), omega=0.0, mu=1.5, e=0.0)
