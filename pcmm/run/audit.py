"""The energy audit of the flights between impacts at one stop (``stats["macro_impacts"]``).

A flight starts at a bounce and ends at the next event.  Over it the kinetic plus gravity
energy may change only by the work of the force elements and the drives (paper Eq. 1's
``tau_a + tau_c``).  The audit measures both sides independently of the integrator's own
energy bookkeeping:

* the energy at the start is the *impulse's*: the event's post-impact kinetic energy at the
  impact posture (what the impact solution gave, before the run re-entered the configuration),
  plus gravity's potential there;
* the energy at the end is that of the state the flight reached (the next event's pre-impact
  state);
* the work is a separate quadrature: 4-point Gauss-Legendre on every recorded step of the
  flight, the states at the nodes from the steps' dense output (:mod:`pcmm.run.dense`: each
  step's interpolant as the integrator took it, its stages or the compiled loop's row of coefficients
  kept, not the step taken again), the
  power ``Q(q, v) . v`` of the force elements plus ``lam . Phi_q v`` of the drives' rows, solved
  at the nodes by a reader of the segment.  The work component the flight integrates with its
  state is not read.

``residual = E_end - E_start - W``.  Anything that moves the flight's start away from the
impulse's result (a wrong re-entry velocity, a restart state shifted off the impact posture)
or an integration that does not conserve what it should shows here; the guard's own location
(how far an impact lies from the stop) is ``guard_residual_max``.

Each flight is measured when it ends, and what only the audit needed (its steps' stages) is then
dropped: a long bouncing run does not hold its flights until it ends.  The measuring reads the
segment through a reader (:meth:`Coordinates.restored`: a copy, warm-started on its own), so the
run's coordinates and their warm starts are left as they were; where nothing would touch them (drives
without a loop, every step's dense output kept: :func:`run_work`) it reads the run's own, which are
the segment's until the next event.
"""
from __future__ import annotations

import numpy as np

from ..model.configuration import Configuration
from ..model import compiled
from ..model.constraints import constrained_accelerations
from .dense import compiled_node_states, dense_states, states_on_rows

RESOLVED_KINETIC = 1e-6  # flights with less rebound energy than this x the first are round-off dominated
GAUSS_NODES, GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(4)
_NODES_1 = GAUSS_NODES + 1  # each step's nodes at t_k + h (x + 1), h its half size
_NODES_1_FLOATS, _WEIGHTS_FLOATS = _NODES_1.tolist(), GAUSS_WEIGHTS.tolist()
_NODE_STEPS = np.arange(4 * 256) // GAUSS_NODES.shape[0]  # the step of each node of a flight's first 256 steps


def mechanical_energy(cfg: Configuration, q, v) -> float:
    """Kinetic plus gravity energy (J): what changes in flight by the work of the force
    elements and drives alone."""
    return cfg.kinetic_energy(q, v) + cfg.gravity_energy(q)


def power(cfg: Configuration, coords, t: float, q, v) -> float:
    """The power (W) of every applied force but gravity: the force elements' ``Q(q, v) . v`` and
    the constraint rows' ``lam . Phi_q v`` (zero for a loop's rows, the motor's for a drive's).
    ``coords`` evaluates, with its force elements (``coords.forces``: a recorded segment's reader
    applies the segment's own)."""
    p = float(coords.forces.generalized(q, v) @ v)
    if len(coords.labels):  # the rows once: coords.accelerations(t, q, v) solves with these
        # (redundant rows: those the motion is solved with, one split; its power is every split's)
        Jq, bias = (coords.solving_rows if coords.redundant else coords.rows)(t, q, v)
        _, lam = constrained_accelerations(cfg, q, v, Jq, bias, forces=coords.forces)
        p += float(lam @ (Jq @ v))
    return p


def flight_work(cfg: Configuration, coords, t, y, stepping, q_start, kept=None) -> float:
    """The work (J) of :func:`power` over a recorded segment ``(t, y)`` (states as columns), by
    Gauss-Legendre quadrature on each step's dense output (``y`` may carry more components
    than the state, as the integrator had them; ``kept``: the steps' dense outputs as the
    integrator took them, :attr:`pcmm.ode.integrators.Segment.dense`).  The nodes are solved from
    the segment's start ``q_start`` by ``coords``, a reader of the segment (:meth:`Coordinates.restored`)."""
    t = np.asarray(t, float)
    if len(t) < 2 or not (len(coords.labels) or coords.forces.names):
        return 0.0  # no step; or no force element and no constraint row: no force but gravity does work
    times, weights, states = _nodes_and_states(t, y, kept, coords.ny)
    fun, method, opts = stepping
    if getattr(fun, "__self__", None) is cfg.coords:  # rhs or rhs_with_power: the reader's own
        fun = getattr(coords, fun.__name__)
    if states is None:
        states = dense_states(t, y, times, (fun, method, opts), kept)
    states = states[:coords.ny]
    values = drive_powers(cfg, coords, times, states)
    if values is None:
        values = tree_powers(coords, times, states)
    if values is None:
        coords.seed(q_start)
        values = np.array([power(cfg, coords, ti, *coords.unpack(ti, states[:, i])) for i, ti in enumerate(times)])
    return float(weights @ values)


def _nodes(t) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss-Legendre nodes and weights of every step of ``t``, step after step."""
    if t.shape[0] == 2:  # one step (most flights of a bouncing run): the same operations on Python floats
        t0, t1 = t.tolist()
        h = (t1 - t0) / 2
        return np.array([t0 + h * x for x in _NODES_1_FLOATS]), np.array([h * w for w in _WEIGHTS_FLOATS])
    h = ((t[1:] - t[:-1]) / 2)[:, None]  # (what np.diff forms)
    return (t[:-1, None] + h * _NODES_1).ravel(), (h * GAUSS_WEIGHTS).ravel()


def _nodes_and_states(t, y, kept, components):
    """``(times, weights, states)``: :func:`_nodes` and :func:`_node_states` (states None where they are not
    read off the compiled loop's rows), in one compiled call where there is one
    (:func:`pcmm.run.dense.compiled_node_states`: the same bits)."""
    got = compiled_node_states(t, y, kept, _NODES_1_FLOATS, _WEIGHTS_FLOATS, components)
    if got is not None:
        return got
    times, weights = _nodes(t)
    return times, weights, _node_states(t, y, times, kept, components)


def _node_states(t, y, times, kept, components):
    """The states at the nodes ``times`` of :func:`_nodes` read off the compiled loop's rows (each node on
    its own step, 4 a step, in order: :func:`pcmm.run.dense.states_on_rows`), or None (another dense output
    kept, or none: :func:`pcmm.run.dense.dense_states`)."""
    n = times.shape[0]
    steps = _NODE_STEPS[:n] if n <= _NODE_STEPS.shape[0] else np.arange(n) // GAUSS_NODES.shape[0]
    return states_on_rows(t, y, times, steps, kept, components)


class _RightHandSideAsked(Exception):
    """A step's dense output was not kept whole: forming it takes the right-hand side."""


def _no_right_hand_side(t, y):
    raise _RightHandSideAsked


def run_work(cfg: Configuration, t, y, stepping, kept) -> float | None:
    """:func:`flight_work` read on the run's own coordinates, where no reader is needed: the rows
    depend on time alone (drives without a loop: no Newton solve, no warm start; the nodes'
    coordinates by ``unpack_many``, which leaves the warm starts alone) and every step's dense
    output was kept formed (none is taken again: the run's right-hand side is never evaluated).
    The same operations on the same values as on a reader of the segment (its partition and
    force elements are the run's until the next event); None where a reader is needed."""
    coords = cfg.coords
    timed = coords.time_rows()
    if kept is None or timed is None or not timed[0].shape[0]:
        return None
    t = np.asarray(t, float)
    if len(t) < 2:
        return 0.0
    times, weights, states = _nodes_and_states(t, y, kept, coords.ny)
    if states is None:
        try:
            states = dense_states(t, y, times, (_no_right_hand_side, *stepping[1:]), kept)
        except _RightHandSideAsked:
            return None
    states = states[:coords.ny]
    values = drive_powers(cfg, coords, times, states)
    return None if values is None else float(weights @ values)


def drive_powers(cfg: Configuration, coords, times, states) -> np.ndarray | None:
    """:func:`power` at every node ``(times, states)`` where the states need no Newton solve and the
    rows depend on time alone (drives without a loop): the same force elements and the same solve
    for the drives' multipliers at each node, in one compiled call where the configuration's drives
    are compiled (``Tree.drive_powers``: its own KKT solve at each node, not the integrator's
    appended power; checked against :func:`python_drive_powers` at probe nodes), to round-off;
    else :func:`python_drive_powers`, to the bit.  None otherwise (loops, a planar joint), and for
    a tree (no rows: :func:`power` is one product there)."""
    timed = coords.time_rows()
    if timed is None or not timed[0].shape[0]:
        return None
    fast = _compiled_drive_powers(cfg, coords)
    if fast is not None:
        return fast(np.asarray(times, float), np.asarray(states, float)[:coords.ny])
    return python_drive_powers(cfg, coords, times, states)


def tree_powers(coords, times, states) -> np.ndarray | None:
    """:func:`power` at every node where there is no constraint row and every force element is linear
    (a tree's springs, dampers and constant torques: ``Q = Q0 - K q - Dv v``): all nodes at once, the
    products over the nodes as matrix products, so each node's power is :func:`power`'s to round-off
    (numpy's products sum in their own order: tests/test_flight_python.py bounds the difference), not
    to the bit.  None otherwise (rows, point springs, coordinates without ``unpack_many``)."""
    forces = coords.forces
    if len(coords.labels) or getattr(forces, "points", True) is not None or not hasattr(forces, "Dv"):
        return None
    many = getattr(coords, "unpack_many", None)
    got = many(times, states) if many is not None else None
    if got is None:
        return None
    Q, V = got
    return np.einsum("ij,ij->j", forces.Q0[:, None] - forces.K @ Q - forces.Dv @ V, V)


def _compiled_drive_powers(cfg: Configuration, coords):
    """The compiled ``drive_powers(times, states)`` of ``coords``'s drives, or None."""
    tree = getattr(coords, "_compiled_drives", lambda: None)()
    if tree is None or not hasattr(tree, "drive_powers") or coords.ny < 2:
        return None
    reference = lambda t, y: python_drive_powers(cfg, coords, t, y)  # noqa: E731
    # the probes are made only where the check runs: once per tree, not at every flight
    return tree.drive_powers if compiled.agrees_on(tree, tree.drive_powers, reference,
                                                   lambda: _drive_power_probes(coords.ny),
                                                   "drive powers") else None


def _drive_power_probes(ny: int) -> list:
    """Probe arguments ``(times, states)`` of ``drive_powers``: two nodes each, a state and its reverse."""
    return [(np.array([0.37 * (j + 1), 0.5 + 0.41 * j]), np.stack([y, y[::-1]], axis=1))
            for j, y in enumerate(compiled._probe_states(ny // 2))]


def python_drive_powers(cfg: Configuration, coords, times, states) -> np.ndarray | None:
    """:func:`power` at every node, to the bit, for drives without a loop: the coordinates of every
    node unpacked at once (``coords.unpack_many``), the rows built once (``coords.time_rows``),
    then the same force elements and the same solve for the drives' multipliers at each node."""
    timed = coords.time_rows()
    if timed is None or not timed[0].shape[0]:
        return None
    many = coords.unpack_many(times, states)
    if many is None:
        return None
    Jq, bias_of = timed
    forces = coords.forces
    Q, V = (np.ascontiguousarray(x.T) for x in many)  # one node a row: contiguous, as unpack gives them
    out = np.empty(len(times))
    for i, ti in enumerate(times):
        q, v = Q[i], V[i]
        p = float(forces.generalized(q, v) @ v)
        _, lam = constrained_accelerations(cfg, q, v, Jq, bias_of(ti), forces=forces)
        out[i] = p + float(lam @ (Jq @ v))
    return out


class FlightAudit:
    """The energy balance of every flight between two impacts at the same contact.

    Consecutive bounces at one stop form a macro-impact; each is reported in
    ``stats["macro_impacts"]`` with its impacts, the times of its first and last event,
    whether it ended in a merge, the largest distance of an impact from its guard's value
    (``guard_residual_max``, m or rad: a rigid stop is struck where the contact closes, so
    this is round-off; a guard that let the bodies sink into the stop shows here, and the
    loads then do work through that depth), its largest flight residual (J, see the module)
    and its largest residual relative to the flight's kinetic energy at the rebound (the
    energy the flight must give back: an approach speed off by a relative d is a relative 2 d
    here).

    The relative figure counts the flights whose rebound energy is above RESOLVED_KINETIC
    times the first flight's (``flights_resolved`` of ``flights``).  Below that the flight
    is so short that double-precision positions decide it: a contact point known to one ulp
    (5.6e-17 m at 0.3 m) under a normal acceleration a shifts the approach speed by
    ``a ulp / v``, which is 1e-6 relative at v = 3e-5 m/s and of order one at 1e-8 m/s."""

    def __init__(self):
        self.macro_impacts: list[dict] = []
        self._open: dict | None = None
        self._kinetic_first = 0.0
        self._start: tuple[float, float] | None = None  # (energy, kinetic energy) the flight starts with

    def event(self, cfg: Configuration, q, event: dict, bounced: bool, guard_residual: float | None) -> None:
        """An event at posture ``q`` of ``cfg``; ``bounced``: a flight at the same stop follows."""
        self._start = None
        if not event.get("impact"):
            self._open = None
            return
        m = self._open
        name = event["name"]
        if m is None or m["transition"] != name:
            m = {"transition": name, "t_first": event["t"], "t_last": event["t"], "impacts": 0, "flights": 0,
                 "merged": False, "guard_residual_max": 0.0, "flight_energy_residual_max": 0.0,
                 "flight_energy_relative_max": 0.0, "flights_resolved": 0}
            self.macro_impacts.append(m)
        m["impacts"] += 1
        if guard_residual is not None:
            m["guard_residual_max"] = max(m["guard_residual_max"], abs(guard_residual))
        m["t_last"] = event["t"]
        m["merged"] = bool(event.get("merge"))
        self._open = m if bounced else None
        if bounced:
            ke = event["kinetic_energy_after"]
            self._start = (ke + cfg.gravity_energy(q), ke)

    def flight(self, cfg: Configuration, steps, stepping, q_end, v_end, kept=None) -> None:
        """The flight just integrated (``steps() -> (t, y, q_start)``: its recorded steps and the
        coordinates it started from; ``kept``: their dense outputs as the integrator took them)
        ended at ``(q_end, v_end)``: measured now (see the module)."""
        m, start = self._open, self._start
        self._start = None
        if m is None or start is None:
            return
        energy_start, kinetic_start = start
        energy_end = mechanical_energy(cfg, q_end, v_end)
        t, y, q_start = steps()
        work = run_work(cfg, t, y, stepping, kept)
        if work is None:
            with cfg.coords.restored(cfg.coords.frozen_state(), q_start, (t, y), cfg.forces) as reader:
                work = flight_work(cfg, reader, t, y, stepping, q_start, kept)
        residual = abs(energy_end - energy_start - work)
        m["flights"] += 1
        m["flight_energy_residual_max"] = max(m["flight_energy_residual_max"], residual)
        if m["flights"] == 1:
            self._kinetic_first = kinetic_start
        if kinetic_start > RESOLVED_KINETIC * self._kinetic_first:
            m["flight_energy_relative_max"] = max(m["flight_energy_relative_max"], residual / kinetic_start)
            m["flights_resolved"] += 1
