"""The Python between two events: the event scanner per accepted step and the flight audit per flight.

    python benchmarks/flight_python.py [SCENE] [--reps 7] [--steps 400]   (default examples/three_bar_cycle.toml)

The scene is run once to warm up, then once more with two functions captured: the first ``--steps``
calls of the event scanner (``pcmm.ode.integrators._Stepper.accept``: the scanner's state before the
call and its arguments) and every flight the energy audit measures (``pcmm.run.audit.FlightAudit.flight``
with what it is handed).  Each capture is then replayed on its own (a fresh copy of the scanner's state
per call; the audit's open macro-impact restored per flight), ``--reps`` times; the median CPU time
(``time.process_time``) per call is printed, the copies' own cost taken out.  The replays read warm
caches: a lower bound of the same calls inside a run, which a load that comes and goes moves far
less than whole runs.  Run it with each tree's sources on ``PYTHONPATH`` to compare two trees (each
replays its own run's calls).  Prints only.
"""
from __future__ import annotations

import argparse
import copy
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pcmm  # noqa: E402
from pcmm.ode import integrators  # noqa: E402
from pcmm.run import audit  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "examples" / "three_bar_cycle.toml"


def _snapshot(st):
    out = copy.copy(st)
    out.g, out.rates, out.ts, out.ys = list(st.g), list(st.rates), list(st.ts), list(st.ys)
    out.kept = None if st.kept is None else list(st.kept)
    return out


def capture(scene, steps: int):
    accepts, flights = [], []
    accept, flight = integrators._Stepper.accept, audit.FlightAudit.flight

    def capturing_accept(self, *args, **kw):
        if len(accepts) < steps:
            accepts.append((_snapshot(self), args, kw))
        return accept(self, *args, **kw)

    def capturing_flight(self, cfg, steps_of, stepping, q_end, v_end, kept=None):
        if self._open is not None and self._start is not None:
            t, y, q0 = steps_of()
            frozen = (t.copy(), y.copy(), q0.copy())
            flights.append((self, dict(self._open), self._start, cfg, lambda: frozen, stepping, q_end, v_end, kept))
        return flight(self, cfg, steps_of, stepping, q_end, v_end, kept)
    integrators._Stepper.accept, audit.FlightAudit.flight = capturing_accept, capturing_flight
    try:
        pcmm.simulate(scene)
    finally:
        integrators._Stepper.accept, audit.FlightAudit.flight = accept, flight
    return accepts, flights


def per_call(run, baseline, n: int, reps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.process_time()
        run()
        t1 = time.process_time()
        baseline()
        t2 = time.process_time()
        times.append(((t1 - t0) - (t2 - t1)) / n)
    return statistics.median(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?", default=str(SCENE))
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--steps", type=int, default=400, help="accepted steps captured (the first of the run)")
    args = ap.parse_args(argv)
    scene = pcmm.load_scene(args.scene)
    pcmm.simulate(scene)  # warm: models built, modules imported
    accepts, flights = capture(scene, args.steps)

    def replay_accepts():
        for st, a, kw in accepts:
            integrators._Stepper.accept(_snapshot(st), *a, **kw)

    def copies():
        for st, _, _ in accepts:
            _snapshot(st)

    def replay_flights():
        for owner, m, start, cfg, steps_of, stepping, q_end, v_end, kept in flights:
            owner._open, owner._start = dict(m), start
            audit.FlightAudit.flight(owner, cfg, steps_of, stepping, q_end, v_end, kept)

    def reopen():
        for owner, m, start, *_ in flights:
            owner._open, owner._start = dict(m), start

    print(f"{Path(args.scene).name}: pcmm from {Path(pcmm.__file__).parent.parent}; load average {os.getloadavg()[0]:.1f}")
    if accepts:
        us = per_call(replay_accepts, copies, len(accepts), args.reps) * 1e6
        print(f"  event scanner: {us:.1f} us per accepted step (the run's first {len(accepts)} steps, "
              f"median of {args.reps} replays)")
    if flights:
        us = per_call(replay_flights, reopen, len(flights), args.reps) * 1e6
        samples = statistics.median(len(f[4]()[0]) for f in flights)
        print(f"  flight audit: {us:.1f} us per flight ({len(flights)} flights, median {samples:g} samples each; "
              f"median of {args.reps} replays)")


if __name__ == "__main__":
    main()
