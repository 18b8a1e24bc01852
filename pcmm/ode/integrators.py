"""Integrators: a registry of methods sharing one contract.

Contract: ``method.integrate(fun, t0, y0, t_bound, events, opts)`` integrates
``y' = fun(t, y)`` from ``t0`` until ``t_bound`` or the first terminal event
and returns a :class:`Segment`.  ``events`` are functions with ``terminal``
and ``direction`` attributes (scipy's convention).  ``opts`` has ``rtol``,
``atol``, ``max_step``, ``step`` (fixed-step methods), ``event_tol`` and
``max_steps``.

Every method hands its accepted steps to one event scanner
(:func:`_scan`).  A guard fires when it changes sign in its direction
between the ends of a step, or when the cubic Hermite model of the guard
(values and rates at both ends) predicts that it enters and leaves within the
step: a grazing impact.  The crossing is bracketed on the method's dense
output and located by Brent's method to ``event_tol`` (s).  Event accuracy
is the dense output's: DOP853 7th order, RK45 4th, RK4 cubic Hermite.

A step with a non-finite state, a step size collapsed to round-off, or more
than ``max_steps`` steps end the run with an error that says which setting
to change; an error or Ctrl-C inside a segment carries the steps already
taken (``exc.segment``) so no result is lost.
"""
from __future__ import annotations

import math
import threading
import warnings
from dataclasses import dataclass

import numpy as np

from .. import _scipy
from ..errors import Repartition, SimulationError
from .dop853 import DOP853, TOO_SMALL_STEP, DenseStep, dense_step, packed_tableau
from .methods import AUTO, INTEGRATOR_NAMES, METHODS  # noqa: F401  (METHODS: the run loop's import)
from .roots import brentq, minimize_bounded

EPS = np.finfo(float).eps


class _ScipyIntegrate:
    """``scipy.integrate`` as the integrators use it, imported on first use: its ``__init__`` costs
    about 0.5 s of CPU at start-up (benchmarks/startup.py).  ``ode``, the driver of the Fortran
    DOP853 that a run on a tree uses, comes alone from its module (:mod:`pcmm._scipy`); the rest
    (scipy's ``OdeSolver`` classes, for the other methods) from the package."""

    def __getattr__(self, name):
        if name == "ode":
            return _scipy.ode()
        import scipy.integrate
        return getattr(scipy.integrate, name)


si = _ScipyIntegrate()


@dataclass
class Segment:
    t: np.ndarray  # (n,)
    y: np.ndarray  # (ny, n)
    event: int | None  # index into events of the event that ended it
    nfev: int
    nsteps: int
    status: int  # 0 reached t_bound, 1 event, -1 failure
    message: str
    # with ``keep_dense``: one entry per accepted step, ``fun -> interpolant`` of that step as the
    # integrator took it (None where the method keeps nothing: :func:`pcmm.run.dense.dense_states`
    # then takes the step again); None without
    dense: list | None = None


class _Counted:
    """The right-hand side with an evaluation counter; a derivative that is not finite stops the
    run at once (scipy's step-size loop would otherwise shrink a NaN step forever, t = NaN)."""

    def __init__(self, fun):
        self.fun, self.n = fun, 0

    def __call__(self, t, y):
        self.n += 1
        return finite_rate(self.fun(t, y), t, y)


def finite_rate(f, t, y):
    """``f`` if every entry is finite, else a :class:`SimulationError` naming the time and state."""
    if type(f) is not np.ndarray:
        f = np.asarray(f, float)
    # one cheap test first (a NaN or an inf makes the sum non-finite; it may overflow, hence the
    # second): a Python sum of a small vector's floats costs a quarter of a numpy dot
    if math.isfinite(sum(f.tolist())) or np.all(np.isfinite(f)):
        return f
    raise SimulationError(
        f"the derivative of the state is not finite at t = {t:.9g} s (state {np.asarray(y).tolist()}): a "
        "velocity, force, stiffness or inertia is too large for floating point; check the initial "
        "values and the model's numbers")


def _too_many_steps(max_steps, t, t0=None, t_bound=None) -> str:
    """The step budget is spent.  A long smooth run needs a larger budget, not another method:
    the message gives the mean step and the budget the whole segment needs at that pace."""
    if t0 is None or t_bound is None or not t > t0:
        return (f"more than {max_steps} steps by t = {t:.9g} s; raise solver.max_steps (--max-steps), "
                "or see docs/performance.md, 'Choosing the method' if the steps are far shorter than the motion's time scale")
    h = (t - t0) / max_steps
    need = math.ceil(max_steps * (t_bound - t0) / (t - t0))
    return (f"more than {max_steps} steps by t = {t:.9g} s (mean step {h:.3g} s since t = {t0:.9g} s); at this "
            f"pace the segment to t = {t_bound:.9g} s needs about {need} steps: raise solver.max_steps "
            f"(--max-steps {need}).  If that step is far shorter than the motion's time scale, a stiff "
            "force element holds it back: see docs/performance.md, 'Choosing the method'")


def _step_collapsed(h, t) -> str:
    size = "round-off" if h is None else f"{h:.3g} s"
    return (f"the step size collapsed to {size} at t = {t:.9g} s: the problem is stiff or singular here; "
            "check forces and stiffness values (an implicit method, Radau or LSODA, pays only for a "
            "strongly damped fast mode: docs/performance.md, 'Choosing the method')")


def _needs_derivative(events) -> bool:
    """Does the graze test need the state derivative at the end of each step?  A guard's rate
    comes from its own ``rate`` when that reads the state alone, else from the derivative."""
    return any(not getattr(e, "rate_from_state", False) for e in events)


def _crossed(g_old, g_new, direction) -> bool:
    """scipy's rule: a sign change (zero counts) in the event's direction."""
    up = g_old <= 0 <= g_new and g_old != g_new
    down = g_old >= 0 >= g_new and g_old != g_new
    return (direction >= 0 and up) or (direction <= 0 and down)


def _rate(e, t, y, f, h, g=None):
    """The guard's time derivative along the flow: its own ``rate`` where it has one,
    else a forward difference.  ``g``: the guard's value at ``(t, y)`` where the caller has it and
    the value is a function of ``(t, y)`` alone (:func:`_pure_value`): the difference starts from it
    (the same bits as asking the guard again)."""
    if getattr(e, "rate", None) is not None:
        return e.rate(t, y, f)
    d = max(1e-7 * abs(h), 1e-12 * max(1.0, abs(t)))
    return (e(t + d, y + d * f) - (e(t, y) if g is None else g)) / d


def _pure_value(e) -> bool:
    """Is the guard's value a function of ``(t, y)`` alone, so that a value already computed may
    stand for asking it again?  A guard on a compiled holding force (``holding``: the compiled solve
    at the state, pcmm.events.holding.guard_value), or one whose value function says so (``pure``: a
    holding force read through coordinates without a Newton solve, pcmm.events.holding._LastState); not
    a guard read through a loop's Newton solve, whose last bits follow its warm start (the previous
    call's solution)."""
    return getattr(e, "holding", None) is not None or getattr(getattr(e, "value", None), "pure", False)


def _hermite_dips(g0, d0, g1, d1, h, direction) -> bool:
    """Does the cubic Hermite g(s) on [0, h] cross zero in ``direction`` inside the step
    although both ends are on the same side, or come within 20 % of the ends' values of it
    (a near miss, then checked on the dense output)?"""
    if (g0 > 0) != (g1 > 0) or g0 == 0 or g1 == 0:
        return False
    if (g0 < 0 and direction < 0) or (g0 > 0 and direction > 0):
        return False  # a dip from this side would cross against the guard's direction
    # cubic in x = s/h: a x^3 + b x^2 + c x + g0; its extrema solve 3a x^2 + 2b x + c = 0
    c = d0 * h
    b = 3 * (g1 - g0) - (2 * d0 + d1) * h
    a = 2 * (g0 - g1) + (d0 + d1) * h
    if a == 0:
        xs = [-c / (2 * b)] if b != 0 else []
    else:
        disc = b * b - 3 * a * c
        if disc < 0:
            return False
        r = disc ** 0.5
        xs = [(-b - r) / (3 * a), (-b + r) / (3 * a)]
    for x in xs:
        if 0.0 < x < 1.0:
            g = ((a * x + b) * x + c) * x + g0
            if (g0 < 0 and g >= 0) or (g0 > 0 and g <= 0) or abs(g) < 0.2 * max(abs(g0), abs(g1)):
                return True
    return False


_NO_RATES = (None,)


def _holding_known(loop, holding: list, m: int):
    """``(values, rates)`` of the guards on a compiled holding force (``holding``: their indices among the
    ``m`` guards) as the compiled loop scanned them at its state (``guard_state()``: the segment's start
    before it runs, a candidate step's end after), None for every other guard and where the loop could
    not solve one (NaN); None where there is none or the loop cannot say (an extension built before it).
    The loop computes them as :meth:`_Stepper.accept` and :func:`_rate` do: the same compiled solve at the
    same state (``HoldingForces.at_state``), the forward difference ``d = max(1e-7 |h|, 1e-12 max(1, |t|))``
    along the same derivative, ``(g(t + d, y + d f) - g) / d``: the same bits, as its ``candidate_start``
    is taken for a candidate's start (:func:`_guards_at_start`)."""
    state = getattr(loop, "guard_state", None) if holding else None
    if state is None:
        return None
    g_all, r_all = state()
    if len(g_all) != m:
        return None
    g, r = [None] * m, [None] * m
    g_list, r_list = g_all.tolist(), r_all.tolist()
    for j in holding:
        gj, rj = g_list[j], r_list[j]
        if math.isfinite(gj) and math.isfinite(rj):
            g[j], r[j] = gj, rj
    return g, r


class _Stepper:
    """Event scanning over accepted steps, shared by every method."""

    def __init__(self, fun, events, opts, t0, y0, f0, t_bound, keep_dense=False, known=None):
        self.fun, self.events, self.opts, self.t_bound = fun, events, opts, t_bound
        self.kept = [] if keep_dense else None  # each accepted step's dense output (Segment.dense)
        self.ts, self.ys = [t0], [np.array(y0, float)]
        # known: (values, rates) at the start, None for a guard to ask (:func:`_holding_known`)
        self.g = [e(t0, self.ys[0]) for e in events] if known is None else \
            [e(t0, self.ys[0]) if g is None else g for e, g in zip(events, known[0])]
        # per guard, read once (not at every step): the value already computed at a step's end stands
        # for asking the guard again in its forward difference (_pure_value), and whether its rate is
        # read at all without the state's derivative:
        # (the guard, its own rate or None: a forward difference (_rate), whether its value is a function of
        # the state alone (_pure_value), whether its rate needs no derivative), and the guards' directions
        self._scan = [(e, getattr(e, "rate", None), _pure_value(e), bool(getattr(e, "rate_from_state", False)))
                      for e in events]
        self._directions = [e.direction for e in events]
        self.rates = [_rate(e, t0, self.ys[0], f0, 1e-6, g if pure else None)
                      for (e, _, pure, _), g in zip(self._scan, self.g)] if events and known is None else \
            [_rate(e, t0, self.ys[0], f0, 1e-6, g if pure else None) if r is None else r
             for (e, _, pure, _), g, r in zip(self._scan, self.g, known[1])] if events else []
        self.count = 0
        self.max_steps = opts.max_steps  # read once: opts may resolve attributes through a fallback

    def accept(self, t_old, y_old, t_new, y_new, f_new, dense, keep=None, known=None):
        """Record one step; return (event index, t_event, y_event) if a guard fires in it.  ``keep``:
        what :attr:`kept` keeps of it (``fun -> interpolant``), where the segment keeps them.  ``known``:
        ``(values, rates)`` at the step's end, None for a guard to ask (:func:`_holding_known`)."""
        if not math.isfinite(y_new @ y_new) and not np.all(np.isfinite(y_new)):  # (the dot: one cheap test)
            raise SimulationError(
                f"the state became {y_new.tolist()} (not finite) at t = {t_new:.9g} s: the method "
                "is unstable at this step size; use a smaller step (solver.step for RK4) or a tighter rtol, "
                "and check forces and stiffness values")
        self.count += 1
        if self.count > self.max_steps:
            raise SimulationError(_too_many_steps(self.max_steps, t_new, self.ts[0], self.t_bound))
        h = t_new - t_old
        if self.count > 100 and 0 < abs(h) < 64 * EPS * max(1.0, abs(t_new)) and t_new != self.t_bound:
            raise SimulationError(_step_collapsed(h, t_new))
        hit = None
        events = self.events
        if events:
            # every value first, then the rates (a loop's guards solve from the previous call's solution:
            # the order of the calls is part of the bits; a known one is a holding guard's, a compiled solve
            # that leaves nothing behind)
            g_new = [e(t_new, y_new) for e in events] if known is None or f_new is None else \
                [e(t_new, y_new) if g is None else g for e, g in zip(events, known[0])]
            if f_new is not None:
                d = max(1e-7 * abs(h), 1e-12 * max(1.0, abs(t_new)))  # _rate's forward difference, once a step
                forward = None
                r_new = []
                rates = known[1] if known is not None else _NO_RATES * len(events)
                for (e, own, pure, _), g, known_rate in zip(self._scan, g_new, rates):
                    if known_rate is not None:
                        r_new.append(known_rate)
                    elif own is not None:
                        r_new.append(own(t_new, y_new, f_new))
                    else:  # (_rate: from the value just computed where it is a function of the state alone)
                        if forward is None:
                            forward = y_new + d * f_new
                        r_new.append((e(t_new + d, forward) - (g if pure else e(t_new, y_new))) / d)
            else:  # only the rates read from the state (_rate)
                r_new = [_rate(e, t_new, y_new, None, h, g if pure else None) if from_state else None
                         for (e, _, pure, from_state), g in zip(self._scan, g_new)]
            g_old, r_old = self.g, self.rates
            for i, direction in enumerate(self._directions):
                g0, g1 = g_old[i], g_new[i]
                # _crossed (inline); else _hermite_dips where both ends' rates are known
                if g0 != g1 and ((direction >= 0 and g0 <= 0 <= g1) or (direction <= 0 and g0 >= 0 >= g1)):
                    pass
                elif r_new[i] is None or r_old[i] is None or not _hermite_dips(g0, r_old[i], g1, r_new[i], h, direction):
                    continue
                found = _locate(events[i], dense(), t_old, t_new, g0, self.opts.event_tol)
                if found is not None and (hit is None or found < hit[1]):
                    hit = (i, found)
            self.g, self.rates = g_new, r_new
        if self.kept is not None:
            self.kept.append(keep)
        if hit is not None:
            i, te = hit
            ye = np.asarray(dense()(te), float)
            self.ts.append(te)
            self.ys.append(ye)
            return i, te, ye
        self.ts.append(t_new)
        self.ys.append(np.array(y_new, float))
        return None

    def segment(self, event, nfev, status, message) -> Segment:
        """The samples so far.  A signal (Ctrl-C, SIGTERM) raised between a sample's time and its
        state being appended leaves one time without its state: that sample is not kept."""
        n = min(len(self.ts), len(self.ys))
        dense = self.kept if self.kept is not None and len(self.kept) == n - 1 else None
        return Segment(np.array(self.ts[:n]), np.array(self.ys[:n]).T.reshape(len(self.ys[0]), n),
                       event, nfev, n - 1, status, message, dense)


#: the compiled locator, ``[locate, enabled]`` where a higher layer registered it (pcmm.model.compiled:
#: pcmm/model/_locate.hpp, this module's :func:`_locate` in C++): ``enabled()`` says whether it may run now
COMPILED_LOCATE: list = []


def _polynomial(sol):
    """``(t_old, h, cont)``: the step's dense output as Hairer's ``contd8`` coefficients (8 x ny, the
    polynomial :class:`_Contd8` evaluates), for DOP853's own dense outputs (the compiled loop's, and
    scipy's ``y_old`` and ``F``, which are the same polynomial evaluated in the same order); else None."""
    cls = type(sol)
    if cls is _Contd8:
        return sol.t_old, sol.h, sol.cont
    if cls is DenseStep or cls is _ScipyDense:  # (the compiled loop's scipy tableau: DenseStep's own bits)
        cont = getattr(sol, "contd8", None)
        if cont is None:
            F = sol.F
            if F.ndim != 2 or F.shape[0] != 7:
                return None
            cont = np.empty((8, F.shape[1]))
            cont[0] = sol.y_old
            cont[1:] = F
            sol.contd8 = cont
        return sol.t_old, sol.h, cont
    return None


def _locate(e, sol, t_a, t_b, g_a, tol):
    """First crossing of ``e`` in its direction on the dense output ``sol`` over [t_a, t_b], or
    None.  The guard is sampled on a grid; where no sample crosses, the sample closest to a
    crossing is refined by a bounded search for the extremum between its neighbours, so a graze
    shorter than the grid spacing is still found.  A guard linear in the state (``Guard.linear``)
    on DOP853's dense output is located by the same algorithm in C++ (:data:`COMPILED_LOCATE`),
    with the same bits; so is a guard read by a compiled evaluator (``Guard.evaluator``: a tree's
    contact gap, its value and rate evaluated in C++ at the same dense states; a loop's joint
    coordinate on the compiled Loop's solutions, the same solves in the same order)."""
    linear = getattr(e, "linear", None)
    if linear is not None and COMPILED_LOCATE and COMPILED_LOCATE[1]():
        poly = _polynomial(sol)
        if poly is not None and len(linear[0]) <= poly[2].shape[1]:
            return COMPILED_LOCATE[0](poly[0], poly[1], poly[2], t_a, t_b, g_a, tol, e.direction, *linear)
    evaluator = getattr(e, "evaluator", None)  # read at the dense state by a compiled evaluator: a contact gap
    if evaluator is not None and len(COMPILED_LOCATE) > 2 and COMPILED_LOCATE[2] is not None and COMPILED_LOCATE[1]():
        poly = _polynomial(sol)
        # a loop's coordinate: its description names the Loop solving the configuration now (None: Python)
        desc = evaluator[0]() if callable(evaluator[0]) else evaluator[0]
        if poly is not None and desc is not None:
            got = COMPILED_LOCATE[2](poly[0], poly[1], poly[2], t_a, t_b, g_a, tol, e.direction, desc, *evaluator[1:])
            if got is not NotImplemented:  # (the Loop declined a solve: Python locates, from the same warm starts)
                return got
    return _locate_python(e, sol, t_a, t_b, g_a, tol)


def _locate_python(e, sol, t_a, t_b, g_a, tol):
    """:func:`_locate` in Python: the reference, and every guard or dense output the compiled
    locator does not take."""
    n = 16
    grid = np.linspace(t_a, t_b, n + 1)
    ys = sol(grid)  # every dense output here takes an array of times: one call, (ny, n + 1)
    many = getattr(e, "many", None)  # the guard at every sample in one call, where it can
    vals = many(grid, ys) if many is not None else None
    if vals is None:
        vals = [e(s, ys[:, k]) for k, s in enumerate(grid)]
    if _crossed(g_a, vals[0], e.direction) and vals[0] != g_a:
        return float(t_a)  # already across at the start of the dense output (round-off)
    xtol = max(tol, 4 * EPS * max(1.0, abs(t_b)))
    rate = e.rate if getattr(e, "rate_from_state", False) else None

    def root(lo, hi, g_lo, g_hi):
        if rate is not None:  # the guard's own rate: Newton's steps, kept in the bracket
            at = _last_state(sol)  # each iterate's value and rate read one dense-output state
            return _bracketed_newton(lambda u: e(u, at(u)), lambda u: rate(u, at(u), None), lo, hi, g_lo, g_hi, xtol)
        return brentq(lambda u: e(u, sol(u)), lo, hi, xtol=xtol, rtol=4 * EPS)
    for k in range(n):
        if _crossed(vals[k], vals[k + 1], e.direction):
            return float(grid[k + 1]) if vals[k + 1] == 0 else root(grid[k], grid[k + 1], vals[k], vals[k + 1])
    # no sample crosses: look for a dip between samples, towards the side the guard crosses to
    sign = 1.0 if e.direction >= 0 else -1.0  # direction >= 0: a crossing makes the guard rise
    k = int(np.argmax([sign * v for v in vals]))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, n)]
    t_x = minimize_bounded(lambda u: -sign * e(u, sol(u)), lo, hi, xatol=xtol)
    g_x = e(t_x, sol(t_x))
    start_side = vals[max(k - 1, 0)]
    if _crossed(start_side, g_x, e.direction) and g_x != start_side:
        return t_x if g_x == 0 else root(lo, t_x, start_side, g_x)
    return None


def _last_state(sol):
    """``sol`` remembering its last instant: a root finder's value and rate at one iterate cost
    one dense-output evaluation (scipy's, some 15 us from Python), not two."""
    last = [None, None]

    def at(u):
        if last[0] != u:
            last[0], last[1] = u, sol(u)
        return last[1]
    return at


def _bracketed_newton(g, dg, lo, hi, g_lo, g_hi, xtol, max_iter=100) -> float:
    """A zero of ``g`` in [lo, hi], where ``g`` changes sign, to ``xtol``: Newton's steps on
    the guard's own rate (``dg``, read from the state), replaced by bisection wherever a step
    would leave the shrinking bracket or not halve the error (Numerical Recipes' rtsafe).
    Near a simple root it converges quadratically: 4 or 5 evaluations from a grid cell where
    Brent's method, which cannot use the rate, took about 16 (with a Newton solve of the loop
    each in a closed loop)."""
    if g_lo == 0:
        return float(lo)
    if g_hi == 0:
        return float(hi)
    neg, pos = (lo, hi) if g_lo < 0 else (hi, lo)  # g(neg) < 0 < g(pos)
    x = lo - g_lo * (hi - lo) / (g_hi - g_lo)  # the secant's zero: the first estimate
    step = step_old = abs(hi - lo)
    f, df = g(x), dg(x)
    for _ in range(max_iter):
        if f == 0:
            return float(x)
        if f < 0:
            neg = x
        else:
            pos = x
        newton_out = ((x - pos) * df - f) * ((x - neg) * df - f) > 0  # the step would leave the bracket
        if newton_out or not df or abs(2 * f) > abs(step_old * df):
            step_old, step = step, 0.5 * (pos - neg)
            x = neg + step
        else:
            step_old, step = step, f / df
            x -= step
        if abs(step) < xtol or abs(pos - neg) < xtol:
            return float(x)
        f, df = g(x), dg(x)
    return float(x)


class _FortranCallbacks(threading.local):
    """The call-backs of the segment the Fortran DOP853 is integrating on this thread.

    scipy's f2py wrapper of DOP853 keeps a reference to each call-back it is handed and never
    releases it (scipy 1.17: one per call to the right-hand side and to ``solout``).  Handed each
    segment's own closures, every segment left them behind with what they hold, and through
    ``ode``'s bound ``_solout`` its integrator and work arrays (0.57 kB per segment of a bouncing
    run once emptied, 10 kB before).  So the Fortran code is only ever handed the two functions
    below, the same objects for the whole process (what leaks is a count on them, no memory), and
    they call the current segment's, set here for the segment's duration."""

    f = None
    solout = None


_FORTRAN = _FortranCallbacks()


def _fortran_rhs(t, y):
    return _FORTRAN.f(t, y)


def _fortran_solout(t, y):
    return _FORTRAN.solout(t, y)


def _guarded_rhs(counted, rhs, zeros, raised):
    """The right-hand side of one segment for the Fortran DOP853 (see :meth:`DOP853F.integrate`),
    called through :func:`_fortran_rhs`."""
    def f(t, y):
        try:
            if raised:
                return zeros
            counted.n += 1
            return rhs(t, y)
        except BaseException as exc:  # incl. Ctrl-C and Repartition: re-raised below
            raised.append(exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ else exc)
            return zeros
    return f


def _run(driver, fun, t0, y0, t_bound, events, opts, keep_dense=False, known=None):
    """Set up the counted right-hand side and the event scanner, let ``driver(counted, f0, st)``
    step (it returns ``(hit, failure)``), and turn what it raises into pcmm errors that carry
    the steps already taken.  ``keep_dense``: the segment keeps each step's dense output
    (:attr:`Segment.dense`); ``known``: guards' values and rates at the start (:func:`_holding_known`)."""
    counted = _Counted(fun)
    f0 = counted(t0, np.asarray(y0, float))
    st = _Stepper(counted, events, opts, t0, y0, f0, t_bound, keep_dense, known)
    try:
        hit, failure = driver(counted, f0, st)
    except (SimulationError, KeyboardInterrupt, Repartition) as exc:
        exc.segment = st.segment(None, counted.n, -1, str(exc))
        raise
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # NaN/inf inside the method
        err = SimulationError(
            f"the integration broke down after t = {st.ts[-1]:.9g} s ({type(exc).__name__}: {exc}): "
            "the state is no longer finite; use a smaller step or tolerance, and check forces and "
            "stiffness values")
        err.segment = st.segment(None, counted.n, -1, str(err))
        raise err from None
    if failure:
        return st.segment(None, counted.n, -1, failure)
    if hit is not None:
        return st.segment(hit[0], counted.n, 1, "event")
    return st.segment(None, counted.n, 0, "reached t_end")


def _scan(steps, st):
    """Feed a method's accepted steps to the event scanner: ``(hit, failure)``.  ``steps`` yields
    ``(t_old, y_old, t_new, y_new, f_new, dense, failure, keep)``."""
    for t_old, y_old, t_new, y_new, f_new, dense, failure, keep in steps:
        if failure:
            return None, failure
        hit = st.accept(t_old, y_old, t_new, y_new, f_new, dense, keep)
        if hit is not None:
            return hit, None
    return None, None


class ScipyMethod:
    """One of scipy's ``OdeSolver`` classes, stepped by pcmm."""

    fixed_step = False

    def __init__(self, name: str, compiled_steps: bool = False):
        self.name = name
        # DOP853 only: stepped by a compiled segment loop with scipy's tableau where the right-hand
        # side has one (what "auto" gives a configuration with drives: method_for), else as always
        self.compiled_steps = compiled_steps

    @property
    def cls(self):
        """scipy's class (scipy.integrate is imported when a run first uses one of these); for
        DOP853, pcmm's step of it (:mod:`pcmm.ode.dop853`: scipy's, bit for bit, without the
        0.5 s import of scipy.integrate)."""
        return DOP853 if self.name == "DOP853" else getattr(si, self.name)

    def integrate(self, fun, t0, y0, t_bound, events, opts, keep_dense=False) -> Segment:
        if self.name == "DOP853" and (self.compiled_steps or COMPILED_SCIPY_STEPS):  # a compiled loop stepping as this class does
            loop, progress = _segment_loop(fun, t0, y0, t_bound, events, opts, 0.0, tableau=packed_tableau(),
                                           keep_dense=keep_dense)
            if loop is not None:  # (the holding guards at the start: as the loop's constructor scanned them)
                return _run(lambda counted, f0, st: self._drive_compiled(loop, progress, counted, st, opts),
                            fun, t0, y0, t_bound, events, opts, keep_dense,
                            _holding_known(loop, _holding_guards(events), len(events)))
        needs_f = _needs_derivative(events)
        stages = keep_dense and self.cls is DOP853  # pcmm's own DOP853 hands its stages out

        def steps(counted, f0, st):
            solver = self.cls(counted, t0, np.array(y0, float), t_bound, rtol=opts.rtol, atol=opts.atol,
                              max_step=opts.max_step)
            while solver.status == "running":
                t_old, y_old = solver.t, solver.y.copy()
                message = solver.step()
                if solver.status == "failed":
                    yield t_old, y_old, solver.t, solver.y, None, None, f"{self.name} failed: {message}", None
                    return
                f_new = getattr(solver, "f", None)  # BDF and LSODA keep none
                if f_new is None and needs_f:
                    f_new = counted(solver.t, solver.y)
                dense = _lazy(solver.dense_output)
                keep = _KeptStages(solver.accepted_stages(), dense) if stages else None
                yield t_old, y_old, solver.t, solver.y, f_new, dense, None, keep
        return _run(lambda counted, f0, st: _scan(steps(counted, f0, st), st), fun, t0, y0, t_bound, events, opts,
                    keep_dense)

    def _drive_compiled(self, loop, progress, counted, st, opts):
        """The segment stepped by the compiled loop as :class:`pcmm.ode.dop853.DOP853` steps it (the
        same steps, round-off apart), its events located on scipy's dense output of the step; a
        step size below round-off ends the segment as scipy's does (a failed segment)."""
        def failure(code):
            FortranDOP853._diagnose(counted, st, opts)  # a non-finite derivative is the cause: say so
            if code == -3:
                return f"{self.name} failed: {TOO_SMALL_STEP}"
            raise SimulationError(FortranDOP853._failure(code, st, opts))
        return _drive_loop(loop, progress, st, lambda: _ScipyDense(*loop.dense()), failure, counted, "DOP853",
                           scipy_row_dense)


def _drive_loop(loop, progress, st, dense, failure, counted, name, from_row):
    """Step a segment by a compiled loop (:func:`_segment_loop`) to its end or its first event:
    ``(hit, failure message)``.  The loop hands back the steps where a guard may fire (or every
    step, where a guard is not affine in the state); those go through :meth:`_Stepper.accept` as
    every method's do, located on ``dense()``, the loop's own dense output of the step.  A failure
    code of the loop goes to ``failure(code)`` (which raises, or returns the failed segment's
    message).  Where the segment keeps its steps' dense outputs, the loop formed each as it
    accepted the step (``take_dense()``, one row each: ``from_row(row, n)`` is its interpolant, kept
    as the row, :class:`_Row`)."""
    events, needs_f = st.events, _needs_derivative(st.events)
    holding = _holding_guards(events)
    keeping = st.kept is not None and hasattr(loop, "take_dense")
    stale = False  # steps recorded since the scanner last saw one: its guard values are not the last step's
    try:
        while True:
            try:
                code = loop.run()
            except BaseException:  # a call the loop handed to Python raised there: the steps before it stand
                steps, rows = loop.take(), loop.take_dense() if keeping else ()
                if len(steps):
                    kept = [_Row(row, from_row) for row in rows]
                    _record_steps(st, steps, kept if len(kept) == len(steps) else None)
                raise
            steps = loop.take()
            rows = loop.take_dense() if keeping else ()
            kept = [_Row(row, from_row) for row in rows]  # one per step accepted, its interpolant formed when asked
            if len(kept) != len(steps) + (code == 1):
                kept = []
            if len(steps):
                _record_steps(st, steps, kept[:len(steps)] if kept else None)
                stale = True
            if code == 1:
                t_old, t_new, y_new, f_new = loop.candidate()
                y_old = st.ys[-1]
                if stale and events:  # the guards at the step's start, as accept leaves them
                    st.g, st.rates = _guards_at_start(loop, events, st, t_old, y_old, t_new)
                stale = False
                lazy = _lazy(dense)
                keep = kept[len(steps)] if len(kept) == len(steps) + 1 else _KeptStages(None, lazy)
                hit = st.accept(t_old, y_old, t_new, y_new, f_new if needs_f else None, lazy, keep,
                                _holding_known(loop, holding, len(events)) if needs_f else None)
                if hit is not None:
                    return hit, None
                if progress is not None and st.count % _PROGRESS_STEPS == 0:
                    progress(float(t_new))
            elif code == 2:  # a pause: Python's turn (Ctrl-C, the progress bar)
                if progress is not None:
                    progress(float(st.ts[-1]))
            elif code == 0:
                if t_bound_reached(st):
                    return None, None
                return None, (f"{name} (compiled) stopped at t = {st.ts[-1]:.17g} s before t_end = "
                              f"{st.t_bound:.17g} s")
            else:
                message = failure(code)
                return None, message
    finally:
        counted.n += loop.counts()[0]


def _holding_guards(events) -> list:
    """The indices of the guards on a compiled holding force (``holding``), which a compiled loop scans."""
    return [j for j, e in enumerate(events) if getattr(e, "holding", None) is not None]


def _guards_at_start(loop, events, st, t_old, y_old, t_new):
    """The guards' values and rates at the start ``(t_old, y_old)`` of a compiled loop's candidate
    step, as :meth:`_Stepper.accept` would have left them at the step before: a guard read from the
    state (affine) asked again; a guard on a holding force (``holding``: no rate of its own, its
    rate a forward difference along the derivative there, over the step that ended there) as the
    loop scanned it (``candidate_start``), or where the loop could not solve it, again in Python.

    A closed loop's guards are read at the start from the loop's solution there, which the loop's
    solves warm-start from the recent ones: the candidate step's stages.  A step run past a change
    point solved its late stages on the other assembly, and the start solved from them landed there
    too, where the singularity guard has the end's sign: the step was accepted across the change
    point (docs/limits.md).  ``start_again`` first puts the loop's warm starts back on the accepted
    state's own solution wherever its stages put the start on another posture (pcmm/model/_loops.hpp:
    start_again; elsewhere nothing changes), so the start is read, and the event located, on the
    run's assembly."""
    g, r = [], []
    start = None
    again = getattr(loop, "start_again", None)  # (an extension built before it: not there)
    if again is not None and any(getattr(e, "loop_scan", None) for e in events):
        again()
    for j, e in enumerate(events):
        if getattr(e, "holding", None) is None:
            g.append(e(t_old, y_old))
            r.append(_rate(e, t_old, y_old, None, t_new - t_old))
            continue
        if start is None:
            start = loop.candidate_start()
        g0, r0 = float(start[0][j]), float(start[1][j])
        if not (math.isfinite(g0) and math.isfinite(r0)):
            h = t_old - st.ts[-2] if len(st.ts) > 1 else t_new - t_old
            g0 = e(t_old, y_old)
            r0 = _rate(e, t_old, y_old, st.fun(t_old, y_old), h)
        g.append(g0)
        r.append(r0)
    return g, r


class _lazy:
    """``make()``, made on the first call and kept (``made``: whether it was)."""

    __slots__ = ("made", "make", "value")

    def __init__(self, make):
        self.make, self.value, self.made = make, None, False

    def __call__(self):
        if not self.made:
            self.value, self.made, self.make = self.make(), True, None
        return self.value


class _KeptStages:
    """A step kept for its dense output (:attr:`Segment.dense`): the interpolant the run already
    formed (an event located in it), else one formed from the step's stages (pcmm's DOP853) with
    the right-hand side it is called with (:meth:`AcceptedStages.dense_output`), else None (no
    stages: the step is taken again)."""

    __slots__ = ("dense", "stages")

    def __init__(self, stages, dense):
        self.stages, self.dense = stages, dense

    def __call__(self, fun):
        if self.dense.made:
            return self.dense()
        return None if self.stages is None else self.stages.dense_output(fun)


def contd8_row_dense(row, n):
    """The interpolant of a row ``(t_old, h, cont (8 n))`` of the compiled loop's ``take_dense()``."""
    return _Contd8(row[0], row[1], row[2:].reshape(8, n))


def scipy_row_dense(row, n):
    """The interpolant of a row ``(t_old, t_new, y_old (n), F (7 n))`` of ``take_dense()`` where the loop
    steps as scipy's DOP853."""
    return _ScipyDense(row[0], row[1], row[2:2 + n], row[2 + n:].reshape(7, n))


class _Row:
    """A step the compiled loop took, kept as the row of its dense output that ``take_dense()`` handed
    back (:attr:`Segment.dense`); ``form`` (:func:`contd8_row_dense` or :func:`scipy_row_dense`) makes
    its interpolant when asked, and :func:`pcmm.run.dense.dense_states` reads a flight's rows in one
    array without forming any."""

    __slots__ = ("row", "form")

    def __init__(self, row, form):
        self.row, self.form = row, form

    def __call__(self, fun):
        return self.form(self.row, (self.row.size - 2) // 8)


class FortranDOP853:
    """Hairer's DOP853 in Fortran (scipy.integrate.ode) for the stepping.

    The Fortran code calls the right-hand side with almost no overhead per
    evaluation (scipy's Python ``OdeSolver`` loop adds several microseconds
    per call, more than a lean right-hand side costs).  Each accepted step is
    scanned for events like every method's; the step that holds an event is
    taken again by DOP853 as scipy implements it (:func:`_dop853_dense`) for its dense output,
    so events are located to DOP853's 7th-order accuracy.
    """

    fixed_step = False
    name = "DOP853F"
    # Hairer's stabilized (PI) step-size control, as his DOPRI5 uses by default (DOP853's own
    # default is 0): fewer rejected steps at the same error (Example 1 at rtol 1e-10: 456 instead
    # of 535 evaluations, 2 instead of 7 rejections; benchmarks/handwritten_baseline.py).
    beta = 0.04

    def integrate(self, fun, t0, y0, t_bound, events, opts, keep_dense=False) -> Segment:
        loop, progress = _segment_loop(fun, t0, y0, t_bound, events, opts, self.beta, keep_dense=keep_dense)
        if loop is not None:
            return _run(lambda counted, f0, st: self._drive_compiled(loop, progress, counted, st, opts),
                        fun, t0, y0, t_bound, events, opts, keep_dense)
        needs_f = _needs_derivative(events)

        def drive(counted, f0, st):
            hits, raised = [], []
            rhs, zeros = counted.fun, np.zeros(len(y0))

            # An exception raised in a call-back does not stop the Fortran code: f2py keeps it
            # until the integration ends (millions of steps later, on garbage).  So a failing
            # right-hand side is recorded and answered with zeros, and solout stops at the next
            # accepted step before recording it.  The trial steps in between mix the last real
            # stage with zeros: they are rejected while the step shrinks (about 15 of them, a
            # few hundred calls that cost nothing), until one is accepted.  Each call-back's
            # whole body is guarded, so even a Ctrl-C between two statements is kept.
            # Finiteness is not tested here, at every evaluation (a sixth of Example 1's run): a
            # non-finite stage makes the Fortran code's error estimate non-finite, the step is
            # rejected, and it stops at once with "step size too small" (-3) within a few hundred
            # evaluations; only then is the cause found (:meth:`_diagnose`).
            f = _guarded_rhs(counted, rhs, zeros, raised)

            def solout(t, y):  # called by the Fortran code after every accepted step
                try:
                    if raised:
                        return -1
                    if t == st.ts[-1]:  # the call at t0, before any step
                        return 0
                    t_old, y_old = st.ts[-1], st.ys[-1]
                    y = y.copy()
                    # the derivative only where a guard's rate needs it (most read it from the state)
                    f_new = counted(t, y) if needs_f else None
                    dense = _lazy(lambda: _dop853_dense(counted, t_old, y_old, t, opts))
                    hit = st.accept(t_old, y_old, t, y, f_new, dense, _KeptStages(None, dense))
                    if hit is not None:
                        hits.append(hit)
                        return -1
                    return 0
                except BaseException as exc:
                    raised.append(exc)
                    return -1
            solver = si.ode(_fortran_rhs).set_integrator(
                "dop853", rtol=opts.rtol, atol=opts.atol, nsteps=opts.max_steps, beta=self.beta,
                max_step=opts.max_step if np.isfinite(opts.max_step) else 0.0)
            solver.set_solout(_fortran_solout)
            solver.set_initial_value(np.array(y0, float), t0)
            # the Fortran code gets the process's solout itself, not the integrator's bound
            # ``_solout`` (a new object per segment, leaked with the integrator: _FortranCallbacks)
            solver._integrator.call_args[2] = _fortran_solout
            outer = _FORTRAN.f, _FORTRAN.solout  # a segment integrated inside a call-back: restored
            _FORTRAN.f, _FORTRAN.solout = f, solout
            try:
                with warnings.catch_warnings():  # scipy warns on a failure code; the message below says it
                    warnings.filterwarnings("ignore", category=UserWarning, module="scipy.integrate._ode")
                    solver.integrate(t_bound)
                code = solver.get_return_code()
            finally:
                _FORTRAN.f, _FORTRAN.solout = outer
            if raised:
                raise raised[0]
            if hits:
                return hits[0], None
            if code < 0:
                self._diagnose(counted, st, opts)
                raise SimulationError(self._failure(code, st, opts))
            if not t_bound_reached(st):
                return None, f"DOP853 (Fortran) stopped at t = {st.ts[-1]:.17g} s before t_end = {t_bound:.17g} s"
            return None, None
        return _run(drive, fun, t0, y0, t_bound, events, opts, keep_dense)

    def _drive_compiled(self, loop, progress, counted, st, opts):
        """The segment stepped by the compiled loop (:func:`_segment_loop`): the same steps as the
        Fortran code's, without Python between them, located on the loop's own dense output."""
        def failure(code):
            self._diagnose(counted, st, opts)
            raise SimulationError(self._failure(code, st, opts))
        return _drive_loop(loop, progress, st, lambda: _Contd8(*loop.dense()), failure, counted, "DOP853",
                           contd8_row_dense)

    @staticmethod
    def _diagnose(counted, st, opts, steps: int = 200) -> None:
        """After a failure: raise the non-finite-derivative error if that is what stopped the
        Fortran code, by stepping on from the last accepted state with the checked right-hand
        side (scipy's DOP853, the same tableau) until the failing stage comes round again."""
        t, y = st.ts[-1], np.array(st.ys[-1], float)
        counted(t, y)  # raises if the derivative at the last accepted state is not finite
        try:
            solver = si.DOP853(counted, t, y, st.t_bound, rtol=opts.rtol, atol=opts.atol)
            for _ in range(steps):
                if solver.status != "running" or solver.step() is not None:
                    return
        except SimulationError:
            raise
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            return

    @staticmethod
    def _failure(code, st, opts) -> str:
        """Hairer's return codes in pcmm's words (the same advice as the other methods')."""
        t = st.ts[-1]
        if code == -2:
            return _too_many_steps(opts.max_steps, t, st.ts[0], st.t_bound)
        if code == -3:
            return _step_collapsed(None, t)
        if code == -4:
            return (f"DOP853 (Fortran) found the problem stiff at t = {t:.9g} s; use a stiff method "
                    "(Radau, LSODA) or check forces and stiffness values")
        return f"DOP853 (Fortran) rejected its input (code {code}) at t = {t:.9g} s"


def t_bound_reached(st) -> bool:
    """Did the last step reach the segment's end?  Hairer's last step, x + (xend - x), may round an
    ulp short: then its time is set to the end."""
    if st.t_bound - st.ts[-1] <= 4 * EPS * max(1.0, abs(st.t_bound)):
        st.ts[-1] = st.t_bound
        return True
    return False


#: accepted steps between two progress reports of the compiled loop (21 DOP853 steps: about the
#: 256 evaluations between two reports of the run loop's wrapper)
_PROGRESS_STEPS = 21

#: Whether the method "DOP853" (scipy's, stepped by pcmm: what a scene asking for it by name gets) may
#: be stepped by a compiled segment loop (pcmm/model/_segment_loop.hpp with scipy's tableau).  Off:
#: its steps cannot be numpy's to the bit, and the method named stays the reference.  ("auto" gives
#: a configuration with drives or loops scipy's DOP853 stepped by that loop where it has one:
#: :data:`AUTO_DOP853`.)  At rtol 1e-10 the error estimate of a
#: step is a sum of stages that nearly cancel (three_bar_cycle's second step: stages of 160 rad/s^2
#: summing to 9e-12, which numpy's BLAS dot product and an in-order sum round 1.6e-14 apart: 0.2 %),
#: so the summation order moves the next step size (by 0.05 % there): examples/three_bar_cycle.toml's
#: steps part at its third step, and its 531
#: event times then differ from the Python-stepped run's by up to 7.6e-10 s (the tolerance's
#: size, not 1e-12), for 2-20 % of its run time in three measurements (benchmarks/segment_loop.py
#: --drives, docs/performance.md).  The compiled
#: right-hand side of drives is what makes that run faster, with the same events to the bit.
COMPILED_SCIPY_STEPS = False

#: compiled segment loops by the type of the object whose bound ``rhs`` (or ``rhs_with_power``) a
#: configuration integrates (a tree's compiled right-hand side; a configuration's coordinates whose
#: drives are compiled): registered by pcmm.model, the layer above.  Each is called as
#: ``make(owner, t0, y0, t_bound, rtol, atol, max_step, max_steps, beta, C, ct, d, direction,
#: every_step, power=..., tableau=...)`` (the last two only where given).
SEGMENT_LOOPS: dict = {}


def _segment_loop(fun, t0, y0, t_bound, events, opts, beta, tableau=None, keep_dense=False):
    """(the compiled loop for this segment, the progress call-back) where ``fun`` is a right-hand
    side (``rhs``, or ``rhs_with_power``: a flight's state with its work appended) whose owner has a
    registered loop (``fun`` may be the run loop's progress wrapper of it, ``__wrapped__``), else
    (None, None): Python steps it, the reference.  ``tableau``: scipy's DOP853 coefficients, packed
    (:func:`pcmm.ode.dop853.packed_tableau`), for a loop that steps as scipy's DOP853; without it
    the loop steps as Hairer's Fortran code with ``beta``."""
    progress = getattr(fun, "progress", None)
    fun = getattr(fun, "__wrapped__", fun)
    owner = getattr(fun, "__self__", None)
    make = SEGMENT_LOOPS.get(type(owner))
    name = getattr(fun, "__name__", None)
    if make is None or name not in ("rhs", "rhs_with_power") or not (np.isscalar(opts.rtol) and np.isscalar(opts.atol)):
        return None, None
    options = {}
    if name == "rhs_with_power":
        options["power"] = True
    if tableau is not None:
        options["tableau"] = tableau
    if keep_dense:
        options["keep_dense"] = True
    y0 = np.array(y0, float)
    ny = y0.size
    C, ct, d, direction, every_step, scans = _guard_scans(events, ny, progress is not None)
    options.update(scans)
    max_step = opts.max_step if np.isfinite(opts.max_step) else 0.0
    args = (owner, float(t0), y0, float(t_bound), float(opts.rtol), float(opts.atol), float(max_step),
            int(opts.max_steps), float(beta), C, ct, d, direction, every_step)
    try:
        try:
            loop = make(*args, **options)
        except TypeError:  # an extension built before keep_dense: the steps are taken again for their dense output
            if not options.pop("keep_dense", False):
                raise
            loop = make(*args, **options)
    except (ValueError, TypeError, RuntimeError):  # a state that is not the tree's: Python steps it
        if "evaluated" not in options and "linear" not in options:
            return None, None
        # the evaluated or linear guards are not this loop's to scan (not a plain tree's state, an extension
        # built before `linear`): every step to Python
        options.pop("evaluated", None)
        options.pop("linear", None)
        options.pop("holding", None)
        try:
            loop = make(*args[:9], np.zeros((0, ny)), np.zeros(0), np.zeros(0), np.zeros(0), True, **options)
        except (ValueError, TypeError, RuntimeError):
            return None, None
    return loop, progress


#: the last few guard sets' scans (:func:`_guard_scans`), by the guards' identities: {key: (guards, scans)}
_SCANS: dict = {}
_SCANS_KEPT = 16


def _guard_scans(events, ny: int, progress: bool):
    """``(C, ct, d, direction, every_step, options)``: how a compiled segment loop scans ``events`` on a
    state of ``ny`` entries (:func:`_scan_guards`), the arrays read-only.  A run re-arms the same guard
    objects at every bounce of a sequence (pcmm.run.loop._guards keeps them), so the scans made for the
    same guards (the same objects, whose scanned fields are set when they are made), the same ``ny`` and
    progress are taken again: the same arguments to the loop, without classifying every guard again at
    every segment."""
    key = (ny, progress, *map(id, events))
    got = _SCANS.get(key)
    if got is not None and len(got[0]) == len(events) and all(a is b for a, b in zip(got[0], events)):
        return got[1]
    scans = _scan_guards(events, ny, progress)
    for a in scans[:4]:
        a.flags.writeable = False
    if len(_SCANS) >= _SCANS_KEPT:
        _SCANS.clear()
    _SCANS[key] = (tuple(events), scans)  # (the guards held: their ids stay theirs while kept here)
    return scans


def _scan_guards(events, ny: int, progress: bool):
    """:func:`_guard_scans` made: ``(C, ct, d, direction, every_step, options)``, the options a dict of
    the kinds of guards the loop scans itself (``solved``, ``holding``, ``evaluated``, ``linear``)."""
    options = {}
    # each guard's one scan, in one pass over the guards (a segment has a few; this runs per segment):
    # affine in the state (Guard.affine), on a compiled holding force (Guard.holding), else a closed
    # loop's guard on its solution (Guard.loop_scan, which its compiled loop scans itself), else a guard
    # read at the state by a compiled evaluator (Guard.evaluator: a tree's contact gap), else a guard
    # linear in the state, its rate read from it (Guard.linear: a driven configuration's joint stop,
    # whose coordinate and rate are state entries; a tree's re-armed joint-angle guard), plain or
    # re-armed after a bounce, which the loop scans as Python reads them.  A progress bar (the run
    # loop's wrapper) is fed every _PROGRESS_STEPS steps, as the wrapper's own count of evaluations
    # did: then every step comes back to Python, as for a guard the loop cannot scan with its rate
    # read from the state (or on a holding force)
    affine, holding, solved, evaluated, linear = [], [], [], [], []
    every_step = progress
    for e in events:
        a, h = getattr(e, "affine", None), getattr(e, "holding", None)
        sv = ev = w = None
        if a is None and h is None:
            sv = getattr(e, "loop_scan", None)
            if sv is None:
                ev = getattr(e, "evaluator", None)
                if ev is None:
                    w = _linear_scan(e, ny)
        if not every_step and h is None and not (
                (a is not None or sv is not None or ev is not None or w is not None)
                and getattr(e, "rate_from_state", False)):
            every_step = True
        affine.append(a)
        holding.append(h)
        solved.append(sv)
        evaluated.append(ev)
        linear.append(w)
    if not every_step:
        scans = [(i, 0, np.asarray(s[1], float), float(s[2]), float(s[3])) if s[0] == "coordinate"
                 else (i, 1, None, 0.0, 0.0) for i, s in enumerate(solved) if s is not None]
        if scans:
            options["solved"] = scans
    if every_step:
        C, ct, d, direction = np.zeros((0, ny)), np.zeros(0), np.zeros(0), np.zeros(0)
    else:
        C = np.zeros((len(events), ny))
        for j, a in enumerate(affine):
            if a is not None and a[0] is not None:  # c over the state's first entries (Guard.affine)
                C[j, :len(a[0])] = a[0]
        ct = np.array([0.0 if a is None else a[1] for a in affine], float)
        d = np.array([0.0 if a is None else a[2] for a in affine], float)
        direction = np.array([e.direction for e in events], float)
        # each kind's guards, where there are any (the loop's options)
        for key, scans in (("holding", [(j, *h) for j, h in enumerate(holding) if h is not None]),
                           ("evaluated", [(j, v[0], float(v[2]) if v[1] else 0.0) for j, v in enumerate(evaluated)
                                          if v is not None]),
                           ("linear", [(j, *w) for j, w in enumerate(linear) if w is not None])):
            if scans:
                options[key] = scans
    return C, ct, d, direction, every_step, options


def _linear_scan(e, ny):
    """``(c, ct, d, r, rt, unfired)`` for a compiled segment loop's scan of a guard linear in the state
    (:attr:`Guard.linear`: value ``c . y + ct t + d``, rate ``r . y + rt``, re-armed with ``unfired`` > 0
    or plain with 0) whose rows fit a state of ``ny`` entries; else None."""
    lin = getattr(e, "linear", None)
    if lin is None:
        return None
    c, ct, d, r, rt, rearm, unfired = lin
    c, r = np.asarray(c, float), np.asarray(r, float)
    if c.size > ny or r.size > ny:
        return None
    return c, float(ct), float(d), r, float(rt), float(unfired) if rearm else 0.0


def _record_steps(st, steps, kept=None) -> None:
    """Accepted steps (rows t, y) the compiled loop took without a candidate event, recorded as
    :meth:`_Stepper.accept` would (the step budget included); ``kept``: their dense outputs, where
    the segment keeps them (:attr:`Segment.dense`)."""
    room = st.max_steps - st.count
    if len(steps) > room:
        keep = steps[:max(room, 0)]
        st.ts.extend(keep[:, 0].tolist())
        st.ys.extend(keep[:, 1:])
        st.count += len(keep)
        raise SimulationError(_too_many_steps(st.max_steps, float(steps[len(keep), 0]), st.ts[0], st.t_bound))
    st.ts.extend(steps[:, 0].tolist())
    st.ys.extend(steps[:, 1:])
    st.count += len(steps)
    if st.kept is not None:
        st.kept.extend([None] * len(steps) if kept is None else kept)


class _ScipyDense(DenseStep):
    """scipy's DOP853 dense output of a step the compiled loop took (:class:`pcmm.ode.dop853.DenseStep`),
    with the same bits; at one time (what a root finder asks, several times per event) its Horner sums
    component by component on Python floats, the very operations ``DenseStep`` does on arrays (a
    quarter of its cost at a few components)."""

    __slots__ = ("_rows", "_start", "_columns")

    def __call__(self, t):
        if not isinstance(t, float) and np.ndim(t) != 0:
            return super().__call__(t)
        columns = getattr(self, "_columns", None)
        if columns is None:
            F = self.F
            # per component (y_old, F[6], F[5], ..., F[0]): DOP853's seven rows, the loop below written
            # out (as pcmm.run.dense.states_on_rows does: the same operations in the same order)
            columns = self._columns = list(zip(self.y_old.tolist(), *F[::-1].tolist())) if F.shape[0] == 7 else ()
        x = (float(t) - float(self.t_old)) / float(self.h)  # as DenseStep's, on floats
        x1 = 1 - x
        if columns:
            return np.array([((((((((0.0 + f6) * x + f5) * x1 + f4) * x + f3) * x1 + f2) * x + f1) * x1 + f0) * x) + y0
                             for y0, f6, f5, f4, f3, f2, f1, f0 in columns], dtype=self.y_old.dtype)
        rows = getattr(self, "_rows", None)
        if rows is None:
            rows = self._rows = [f.tolist() for f in self.F[::-1]]
            self._start = self.y_old.tolist()
        out = []
        for j, y0 in enumerate(self._start):
            acc = 0.0
            for i, f in enumerate(rows):  # y += f, then y *= x or (1 - x), alternately
                acc = (acc + f[j]) * (x if i % 2 == 0 else x1)
            out.append(acc + y0)
        return np.array(out, dtype=self.y_old.dtype)


class _Contd8:
    """DOP853's 7th-order dense output over one step, from the coefficients of Hairer's ``contd8``
    (``cont``, 8 x ny) that the compiled loop computes; like scipy's dense outputs it takes a time
    (returns (ny,)) or an array of times (returns (ny, n))."""

    def __init__(self, t_old, h, cont):
        self.t_old, self.h, self.cont = t_old, h, cont

    def __call__(self, t):
        s = (np.asarray(t, float) - self.t_old) / self.h
        s1 = 1.0 - s
        c = self.cont if s.ndim == 0 else self.cont[:, :, None]
        par = c[4] + s * (c[5] + s1 * (c[6] + s * c[7]))
        return c[0] + s * (c[1] + s1 * (c[2] + s * (c[3] + s1 * par)))


def _dop853_dense(fun, t_a, y_a, t_b, opts):
    """DOP853's 7th-order dense output over one step [t_a, t_b] of the Fortran code: DOP853 as
    scipy implements it (the same tableau and error control, :mod:`pcmm.ode.dop853`) started
    with that step size.  It normally takes the step in one; where it splits it, the pieces are
    joined."""
    sol, message = dense_step(fun, t_a, y_a, t_b, opts.rtol, opts.atol)
    if sol is None:
        raise SimulationError(f"DOP853 failed while re-integrating the step [{t_a:.9g}, {t_b:.9g}] s "
                              f"that holds an event: {message}")
    return sol


class FixedStepRK4:
    """Classical Runge-Kutta with a fixed step (the paper's MATLAB route).

    Its dense output is the cubic Hermite interpolant of each step (two evaluations: with
    ``keep_dense`` its steps keep nothing, :func:`pcmm.run.dense.dense_states` forms it again)."""

    fixed_step = True
    name = "RK4"

    def integrate(self, fun, t0, y0, t_bound, events, opts, keep_dense=False) -> Segment:
        def steps(counted, f0, st):
            h = opts.step
            t, y, f = t0, np.array(y0, float), f0
            tol = 1e-15 * max(1.0, abs(t_bound))
            while t < t_bound - tol:
                hh = min(h, t_bound - t)
                # a step that ends within tol of t_bound ends on it: accumulated steps of h fall an
                # ulp or so short of it, and the run would end (and say it ended) at 0.9999999999999999
                last = t_bound - (t + hh) <= tol
                if last:
                    hh = t_bound - t
                if y.size == 0:  # nothing to integrate (a locked or fully driven configuration)
                    t_new = t_bound if last else t + hh
                    f_new = counted(t_new, y)
                    yield t, y, t_new, y, f_new, _lazy(lambda a=(t, y, f, t_new, y, f_new): _hermite(*a)), None, None
                    t = t_new
                    continue
                k2 = counted(t + hh / 2, y + hh / 2 * f)
                k3 = counted(t + hh / 2, y + hh / 2 * k2)
                k4 = counted(t + hh, y + hh * k3)
                y_new = y + hh / 6 * (f + 2 * k2 + 2 * k3 + k4)
                t_new = t_bound if last else t + hh
                f_new = counted(t_new, y_new) if np.all(np.isfinite(y_new)) else y_new
                yield t, y, t_new, y_new, f_new, _lazy(lambda a=(t, y, f, t_new, y_new, f_new): _hermite(*a)), None, None
                t, y, f = t_new, y_new, f_new
        return _run(lambda counted, f0, st: _scan(steps(counted, f0, st), st), fun, t0, y0, t_bound, events, opts,
                    keep_dense)


def _hermite(t0, y0, f0, t1, y1, f1):
    """The cubic Hermite interpolant of a step; like scipy's dense outputs it takes a time
    (returns (ny,)) or an array of times (returns (ny, n))."""
    h = t1 - t0
    outer = np.multiply.outer

    def y(s):
        x = (np.asarray(s, float) - t0) / h
        h00, h10 = 2 * x**3 - 3 * x**2 + 1, x**3 - 2 * x**2 + x
        h01, h11 = -2 * x**3 + 3 * x**2, x**3 - x**2
        return outer(y0, h00) + outer(h * f0, h10) + outer(y1, h01) + outer(h * f1, h11)
    return y


INTEGRATORS = {name: ScipyMethod(name) for name in ("RK45", "DOP853", "Radau", "LSODA", "BDF", "RK23")}
INTEGRATORS["DOP853F"] = FortranDOP853()
INTEGRATORS["RK4"] = FixedStepRK4()
assert tuple(INTEGRATORS) == INTEGRATOR_NAMES, "pcmm.ode.methods names every integrator of the registry"

#: what "auto" gives a configuration with drives or loops: scipy's DOP853 (its tableau, error norm and
#: step-size control), stepped by the compiled segment loop where the right-hand side has one (drives
#: without a loop), else by pcmm.ode.dop853 in Python.  Its steps are the Python ones round-off apart
#: (the error estimate's sums in another order), not Hairer's DOP853F (another step-size control: the
#: event times of three_bar_cycle then move by the tolerance's size, 2.3e-8 s, not 2.3e-9 s);
#: docs/performance.md, "Drives without loops".
AUTO_DOP853 = ScipyMethod("DOP853", compiled_steps=True)

# "auto": per configuration, the cheaper method at equal accuracy (docs/benchmarks/work_precision.md).
# On a tree the right-hand side is one aba, and scipy's Python step loop would cost more than it:
# Hairer's Fortran DOP853 is about 2x faster there, with event times as accurate (Example 1 at rtol
# 1e-10: 3.9e-13 s against DOP853's 7.2e-13 s).  With loops or drives the Newton-solved right-hand
# side dominates and every impact re-takes a step for the dense output, so scipy's DOP853 is cheaper.


def method_for(name: str, constrained: bool):
    """The integrator a configuration uses under the run's ``method`` setting."""
    if name == AUTO:
        return AUTO_DOP853 if constrained else INTEGRATORS["DOP853F"]
    return INTEGRATORS[name]

