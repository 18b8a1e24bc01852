"""What the flight-energy audit costs a run in evaluations: the calls of a loop configuration's
right-hand side with the work appended (``rhs_with_power``: the flights' own steps, and before the
audit reused their dense outputs, every step taken again for it), the Newton unpacks
(``PartitionedCoordinates.unpack``, and ``_unpack``: those a Newton solve in Python answers, not a
cache), the calls for a segment reader's compiled KKT solve (``_reader_kkt``, which solves where the
reader has a compiled loop: before Loop.rows the audit's power asked for one at every quadrature node
only to keep its rows, then solved again in Python; a tree without that method prints none), and
the CPU time inside the audit (``FlightAudit.flight``, or
``FlightAudit.finish`` in trees that measured the flights when the run ended), of one run, warm.

    python benchmarks/audit_counts.py [SCENE]   (default examples/double_folded.toml)

Run with another tree's sources first on ``PYTHONPATH`` to count that tree (the figures in
docs/performance.md: ``git archive 89f8a17`` against the audit's change); prints only.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import functools  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import pcmm  # noqa: E402
from pcmm.model import partitioned  # noqa: E402
from pcmm.run import audit  # noqa: E402


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    path = Path(argv[0]) if argv else Path(pcmm.__file__).resolve().parents[1] / "examples" / "double_folded.toml"
    scene = pcmm.load_scene(path)
    pcmm.simulate(scene)  # warm
    counts = {"rhs_with_power": 0, "unpack": 0, "_unpack": 0, "_reader_kkt": 0, "audit_s": 0.0}
    cls = partitioned.PartitionedCoordinates

    def counted(name):
        real = getattr(cls, name)

        @functools.wraps(real)  # the audit reads a method's name (its reader's own)
        def call(self, *a, **kw):
            counts[name] += 1
            return real(self, *a, **kw)
        return call

    def timed(real):
        @functools.wraps(real)
        def call(*a, **kw):
            t0 = time.process_time()
            try:
                return real(*a, **kw)
            finally:
                counts["audit_s"] += time.process_time() - t0
        return call
    cls.rhs_with_power, cls.unpack, cls._unpack = counted("rhs_with_power"), counted("unpack"), counted("_unpack")
    readers = hasattr(cls, "_reader_kkt")
    if readers:
        cls._reader_kkt = counted("_reader_kkt")
    part = "finish" if hasattr(audit.FlightAudit, "finish") else "flight"
    setattr(audit.FlightAudit, part, timed(getattr(audit.FlightAudit, part)))
    traj = pcmm.simulate(scene)
    print(f"{pcmm.__file__}: {path.name}: {len(traj.events)} events; rhs_with_power {counts['rhs_with_power']}, "
          f"unpack {counts['unpack']} (Newton solves in Python, _unpack: {counts['_unpack']}), "
          + (f"reader KKT calls (_reader_kkt) {counts['_reader_kkt']}, " if readers else "")
          + f"audit ({part}) {1e3 * counts['audit_s']:.0f} ms CPU")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
