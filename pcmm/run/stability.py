"""Is the run still computing physics?  The checks that name the true cause when an integration
blows up, before anything downstream (a contact's normal, a loop's posture, a collapsing step)
takes the blame for it:

* :func:`fixed_step_instability`: a fixed-step method (RK4) is stable for a linear mode of
  eigenvalue ``lambda`` only where its amplification per step ``|R(h lambda)| <= 1``, with
  ``R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24`` (on the imaginary axis, an undamped spring, up to
  ``h omega = 2 sqrt 2 = 2.83``; on the negative real axis to 2.79).  A mode that ``R`` amplifies
  by more than both 1 and the exact ``|exp(h lambda)|`` grows because of the step alone, so
  every later number is meaningless.  The eigenvalues are those of the state equation's
  Jacobian ``df/dy`` (central differences) at the state the segment starts from.
* :func:`unphysical_speed`: a point of a body faster than light (or not finite): an initial
  velocity that cannot be meant, or a state an integration has blown up to.

Both return the message (naming the time, the cause and the setting or field to change), or
``None`` when all is well.
"""
from __future__ import annotations

import math
import re

import numpy as np
import pinocchio as pin

from ..model.configuration import Configuration

SPEED_OF_LIGHT = 299_792_458.0  # m/s
#: a mode counts as amplified by the step when |R(h lambda)| exceeds max(1, |exp(h lambda)|) by this
#: relative margin (finite-difference noise in the Jacobian stays far below it)
AMPLIFICATION_TOL = 1e-6


def rk4_amplification(z):
    """RK4's factor per step on ``y' = lambda y`` at ``z = h lambda`` (its stability function)."""
    return 1 + z + z * z / 2 + z ** 3 / 6 + z ** 4 / 24


def jacobian(fun, t: float, y: np.ndarray) -> np.ndarray:
    """``df/dy`` at (t, y) by central differences, each step relative to the coordinate."""
    n = y.size
    J = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1e-6 * max(1.0, abs(float(y[j])))
        J[:, j] = (np.asarray(fun(t, y + e), float) - np.asarray(fun(t, y - e), float)) / (2 * e[j])
    return J


def _spurious(eigenvalues: np.ndarray, h: float) -> np.ndarray:
    """The eigenvalues that RK4 at step h amplifies beyond the exact solution (and beyond 1)."""
    z = h * eigenvalues
    amp = np.abs(rk4_amplification(z))
    exact = np.exp(np.clip(z.real, -700.0, 700.0))
    return (amp > 1 + AMPLIFICATION_TOL) & (amp > exact * (1 + AMPLIFICATION_TOL))


def stable_step(eigenvalues: np.ndarray, h: float) -> float:
    """The largest step up to ``h`` at which no eigenvalue is amplified (bisection)."""
    lo, hi = 0.0, h
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if not _spurious(eigenvalues, mid).any() else (lo, mid)
    return lo


def fixed_step_instability(cfg: Configuration, fun, t: float, y: np.ndarray, h: float, method: str = "RK4"):
    """The message when a fixed step ``h`` is beyond the stability limit of the fastest mode of
    ``y' = fun(t, y)`` at (t, y) in ``cfg`` (see the module's note), else None."""
    y = np.asarray(y, float)
    if y.size == 0 or not np.all(np.isfinite(y)):
        return None
    try:
        with np.errstate(all="ignore"):
            lam = np.linalg.eigvals(jacobian(fun, t, y))
    except Exception:  # noqa: BLE001 - a diagnosis; a state where the rhs fails tells nothing
        return None
    lam = lam[np.isfinite(lam)]
    bad = _spurious(lam, h)
    if not bad.any():
        return None
    worst = lam[bad][np.argmax(np.abs(lam[bad]))]
    rate = abs(worst)
    amp = abs(rk4_amplification(h * worst))
    ok = stable_step(lam, h)
    advice = f"{0.9 * ok:.2g}"
    return (f"t = {t:.9g} s, configuration '{cfg.name}': the fixed-step method {method} is unstable at "
            f"solver.step = {h:.3g} s: the fastest mode of the motion (a stiffness: a spring, a contact "
            f"law, a stiff loop) has |lambda| = {rate:.4g} 1/s (period {2 * math.pi / rate:.3g} s), so "
            f"step x |lambda| = {h * rate:.3g}, beyond {method}'s stability limit of about 2.8, and each step "
            f"multiplies that mode by {amp:.3g} whatever the physics does: every number after this "
            f"instant would be meaningless.  Set solver.step (--step) to {advice} s or less (stable up to "
            f"{ok:.3g} s), or solver.method = \"DOP853\" (an adaptive method chooses its own step)")


def fastest_point(cfg: Configuration, q: np.ndarray, v: np.ndarray) -> tuple[float, str]:
    """(speed in m/s, where): the fastest of every body's joint origin and centre of mass
    (inf when a velocity is not finite)."""
    if cfg.nv == 0:
        return 0.0, ""
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
        return math.inf, "a coordinate or velocity that is not finite"
    model, data = cfg.model, cfg.data
    with np.errstate(all="ignore"):
        pin.forwardKinematics(model, data, cfg.to_pin(q), v)
    best, where = 0.0, ""
    # on Python floats: numpy's cross product of two 3-vectors cost more than the forward
    # kinematics (this runs at every run's start, a twentieth of Example 1's run)
    for i in range(1, model.njoints):
        m = data.v[i]
        vx, vy, vz = m.linear.tolist()
        wx, wy, wz = m.angular.tolist()
        lx, ly, lz = model.inertias[i].lever.tolist()
        # the centre of mass: v + omega x lever
        for what, vel in (("origin", (vx, vy, vz)),
                          ("centre of mass", (vx + (wy * lz - wz * ly), vy + (wz * lx - wx * lz), vz + (wx * ly - wy * lx)))):
            speed = math.hypot(math.hypot(vel[0], vel[1]), vel[2])
            if not speed <= best:  # a NaN speed wins too
                best, where = speed, f"the {what} of the body on joint '{model.names[i]}'"
    return (math.inf if math.isnan(best) else best), where


def unphysical_speed(cfg: Configuration, q: np.ndarray, v: np.ndarray) -> str | None:
    """'<where> moves at <speed> m/s, faster than light (...)' when a body point does, else None."""
    speed, where = fastest_point(cfg, q, v)
    if speed <= SPEED_OF_LIGHT:
        return None
    return (f"{where} moves at {speed:.3g} m/s, faster than light ({SPEED_OF_LIGHT:.6g} m/s)" if math.isfinite(speed)
            else f"{where} is not finite")


def largest_velocity(cfg: Configuration, v: np.ndarray) -> str:
    """'J1 = 1e+150' for the joint with the largest velocity (the one to look at first)."""
    values = {name: float(np.max(np.abs(np.atleast_1d(x)))) for name, x in cfg.by_joint(v).items()}
    if not values:
        return ""
    name = max(values, key=lambda n: values[n] if not math.isnan(values[n]) else math.inf)
    x = cfg.by_joint(v)[name]
    return f"{name} = " + (f"{x:.6g}" if np.ndim(x) == 0 else "(" + ", ".join(f"{c:.6g}" for c in x) + ")")


def blow_up(cfg: Configuration, exc, t: float, q, v, method, step: float) -> str | None:
    """Why a run failed, when the failure is a symptom of a blown-up integration: the state it
    failed in (the failing segment's last step, else (t, q, v)) is not physical.  Then neither
    the normal, the posture nor the step-size control that the first message blames is the cause,
    the integration is; None otherwise."""
    seg = getattr(exc, "segment", None)
    if seg is not None and seg.t.size > 1:
        try:
            t = float(seg.t[-1])
            q, v = cfg.coords.unpack(t, np.asarray(seg.y[:cfg.coords.ny, -1], float))
        except Exception:  # noqa: BLE001 - a loop that cannot close there: the (t, q, v) given
            pass
    try:
        fast = unphysical_speed(cfg, np.asarray(q, float), np.asarray(v, float))
    except Exception:  # noqa: BLE001 - a diagnosis; never let it mask the error itself
        return None
    if fast is None:
        return None
    name = getattr(method, "name", str(method))
    cause = (f"the fixed-step method {name} at solver.step = {step:.3g} s is beyond its stability limit "
             f"for a stiffness the motion met (a contact law, a spring): lower solver.step (--step), or "
             f"set solver.method = \"DOP853\" (an adaptive method chooses its own step)"
             if getattr(method, "fixed_step", False) else
             "check the stiffness, damping and mass values and the initial state")
    first = str(exc.problems[0]) if getattr(exc, "problems", None) else str(exc)
    return (f"t = {t:.9g} s, configuration '{cfg.name}': the integration blew up: {fast}; {cause}.  What "
            f"was reported there is a symptom of it, not the cause: {first[:160]}{'...' if len(first) > 160 else ''}")


_AT_T = re.compile(r"at t = ([-+0-9.eE]+) s")
#: a constraint Jacobian with a larger condition number is near a singular posture
SINGULAR_COND = 1e8


def trial_time(cfg: Configuration, exc, t: float) -> str | None:
    """When a failure inside a segment names a time other than the segment's last accepted step
    (a Newton solve of a loop at a trial step of the integrator, possibly as far as t_end), the
    run stopped at that last step: say so, and what the constraint Jacobian's condition number
    there says (a regular posture or a singular one); None otherwise."""
    seg = getattr(exc, "segment", None)
    problems = getattr(exc, "problems", None)
    if seg is None or not seg.t.size or not problems:
        return None
    t_stop, text = float(seg.t[-1]), str(problems[0])
    m = _AT_T.search(text)
    try:
        t_said = float(m.group(1)) if m else None
    except ValueError:
        return None
    if t_said is None or abs(t_said - t_stop) <= 1e-6 * max(1.0, abs(t_stop)) + 1e-12:
        return None
    posture = ""
    try:
        q, _ = cfg.coords.unpack(t_stop, np.asarray(seg.y[:cfg.coords.ny, -1], float))
        _, Jq = cfg.coords.loop_rows(q)
        if Jq.size and "cannot be closed" in text:  # a Newton solve's failure (not, e.g., redundant rows violated)
            cond = float(np.linalg.cond(Jq))
            posture = (f"; there the loop's constraint Jacobian has condition number {cond:.3g}, " +
                       ("a regular posture: the integrator's trial step was too long for the loop's "
                        "Newton solve, not a singular posture (a smaller solver.max_step helps)"
                        if cond < SINGULAR_COND else "near a singular posture"))
    except Exception:  # noqa: BLE001 - a diagnosis; never let it mask the error itself
        pass
    return (f"t = {t_stop:.9g} s, configuration '{cfg.name}': the run stopped here, at its last accepted "
            f"step{posture}.  The failure came at t = {t_said:.9g} s, where the integrator tried a step to: {text}")


def diagnose(cfg: Configuration, exc, t: float, q, v, method, step: float) -> str | None:
    """The message that names the true time and cause of a failed run (:func:`blow_up`, then
    :func:`trial_time`), or None to keep the failure's own."""
    return blow_up(cfg, exc, t, q, v, method, step) or trial_time(cfg, exc, t)
