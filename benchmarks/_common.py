"""Shared helpers of the pcmm benchmarks (not part of pcmm).

Timing rules every script follows: a ratio is only ever formed from figures
measured in the same process, repeated and interleaved (the repetitions are the
outer loop, so a burst of load from another user of the machine hits every
variant alike), and summarised by the median.  No figure here is asserted by a
test.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import importlib
import os
import platform
import re
import statistics
import shlex
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
DOCS = ROOT / "docs" / "benchmarks"


def machine() -> dict:
    """CPU model, cores, versions, date and load (the machine is shared: the load says how noisy)."""
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import pinocchio
    import scipy
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    try:
        load = "%.2f %.2f %.2f" % os.getloadavg()
    except OSError:
        load = "n/a"
    return {
        "cpu": cpu, "cores": os.cpu_count(), "usable_cores": usable,
        "python": platform.python_version(), "pin": pinocchio.__version__, "scipy": scipy.__version__,
        "numpy": np.__version__, "platform": platform.platform(),
        "date": _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z"), "load_at_start": load,
        "pcmm_sources": pcmm_fingerprint(),
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "unset (OpenBLAS default: one per core)"),
    }


def pcmm_fingerprint() -> str:
    """sha1 (10 hex) of pcmm's source files as imported (every subpackage's, and the compiled
    extension's C++): pcmm is edited while benchmarks run, so every page records which sources it
    measured (and their latest modification time)."""
    import pcmm
    root = Path(pcmm.__file__).parent  # every subpackage's sources and the compiled extension's
    files = sorted(f for pattern in ("*.py", "*.cpp", "*.hpp") for f in root.rglob(pattern))
    h = hashlib.sha1()
    for f in files:
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    newest = max(f.stat().st_mtime for f in files)
    return f"{h.hexdigest()[:10]} (newest file {_dt.datetime.fromtimestamp(newest).astimezone():%Y-%m-%d %H:%M:%S %Z})"


def machine_md(info: dict) -> str:
    return (f"Machine: {info['cpu']}, {info['cores']} cores ({info['usable_cores']} usable, shared with "
            f"other users; load average at start {info['load_at_start']}); Python {info['python']}, "
            f"pin (Pinocchio) {info['pin']}, scipy {info['scipy']}, numpy {info['numpy']}; "
            f"{info['platform']}; OPENBLAS_NUM_THREADS {info['blas_threads']}; pcmm sources "
            f"{info['pcmm_sources']}; {info['date']}.")


def command_line() -> str:
    script = Path(sys.argv[0]).resolve()
    try:
        script = script.relative_to(ROOT)
    except ValueError:
        pass
    return shlex.join(["python", str(script)] + sys.argv[1:])  # quoted: it is pasted into a shell


def median(xs):
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return statistics.median(xs) if xs else float("nan")


def per_call(fn, args=(), n=2000) -> float:
    """Seconds per call of ``fn(*args)`` over ``n`` calls (one sample)."""
    t0 = time.perf_counter()
    for _ in range(n):
        fn(*args)
    return (time.perf_counter() - t0) / n


def md_table(header: list[str], rows: list[list]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(c) for c in r) + " |")
    return "\n".join(out)


def fmt(x, spec=".2e") -> str:
    if x is None:
        return "—"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, str):
        return x
    if not np.isfinite(x):
        return "—"
    return format(x, spec)


def scene_copy(src: Path, dest_dir: Path, name: str, edit=None) -> Path:
    """Copy a scene TOML into ``dest_dir`` with its URDF paths made absolute; ``edit(text) -> text``."""
    text = Path(src).read_text()

    def absolute(m):
        return f'urdf = "{(Path(src).parent / m.group(1)).resolve()}"'
    text = re.sub(r'urdf\s*=\s*"([^"]+)"', absolute, text)
    if edit is not None:
        text = edit(text)
    dest_dir.mkdir(parents=True, exist_ok=True)
    out = dest_dir / name
    out.write_text(text)
    return out


def loglog_slope(x, y) -> float:
    x, y = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    return float(np.polyfit(x, y, 1)[0])


# ---- instrumentation: time every integrated segment of a run ------------------------------
class SegmentTiming(NamedTuple):
    t0: float  # start of the segment (s)
    ny: int  # state size (0: a fully driven or locked configuration, sampled, not integrated)
    seconds: float  # wall time of the integrator call
    nfev: int
    nsteps: int


@contextmanager
def timed_segments(log: list):
    """For the duration of a run, wrap every method of pcmm's integrator registry so that each
    integrated segment appends a :class:`SegmentTiming` to ``log`` (one perf_counter pair per
    segment).  pcmm itself is not modified."""
    sim = importlib.import_module("pcmm.run.loop")
    integ = importlib.import_module("pcmm.ode.integrators")  # method_for ("auto") picks from this module's registry
    original = sim.INTEGRATORS

    class Timed:
        def __init__(self, inner):
            self.inner, self.fixed_step, self.name = inner, inner.fixed_step, inner.name

        def integrate(self, fun, t0, y0, t_bound, events, opts, **kw):
            t = time.perf_counter()
            seg = self.inner.integrate(fun, t0, y0, t_bound, events, opts, **kw)
            log.append(SegmentTiming(t0, len(y0), time.perf_counter() - t, seg.nfev, seg.nsteps))
            return seg
    sim.INTEGRATORS = integ.INTEGRATORS = {k: Timed(v) for k, v in original.items()}
    try:
        yield
    finally:
        sim.INTEGRATORS = integ.INTEGRATORS = original


# ---- memory: what a finished run retains --------------------------------------------------
def traced_run(scene, t_end: float, warm_up: float = 3.0, traced: bool = True, **simulate_kw):
    """Simulate ``scene`` to ``t_end`` under ``tracemalloc`` (if ``traced``), after a warm-up run to
    ``warm_up`` s (models built, modules imported: neither is counted).  Returns (trajectory,
    figures): ``retained``, the bytes still allocated after the run and a collection (what the
    finished run holds, its trajectory included); ``peak``, the traced peak above the start (both
    None untraced); ``cpu_s``, the run's CPU time (tracing slows it); ``rss_peak_kb``, the process's
    peak RSS (all of it: Python, numpy, scipy, Pinocchio and the run).  ``simulate_kw`` goes to
    :func:`pcmm.simulate` (``store=``)."""
    import gc
    import resource
    import tracemalloc

    import pcmm
    pcmm.simulate(scene, pcmm.RunOptions(t_end=warm_up))
    gc.collect()
    if traced:
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
    t0 = time.process_time()
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end), **simulate_kw)
    cpu = time.process_time() - t0
    gc.collect()
    retained = peak = None
    if traced:
        current, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        retained, peak = current - base, peak - base
    return traj, dict(retained=retained, peak=peak, cpu_s=cpu,
                      rss_peak_kb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def rss_kb() -> int:
    """The process's resident set size now (kB; Linux's /proc/self/status, else 0)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


class RssTrace:
    """A run's ``progress(t)`` that reads the resident set size each time the run passes another
    ``every`` s of simulated time, and prints ``rss t=... kb=...`` to stderr as it goes (a run
    stopped before its end leaves its trace)."""

    def __init__(self, every: float):
        self.every, self.next, self.points = every, every, []

    def __call__(self, t: float) -> None:
        if t >= self.next:
            self.points.append((t, rss_kb()))
            print(f"rss t={t:.6g} kb={self.points[-1][1]}", file=sys.stderr, flush=True)
            while self.next <= t:
                self.next += self.every


def traced_run_in_child(scene_path: Path, t_end: float, store: Path | None = None, chunk: int | None = None,
                        traced: bool = True, rss_every: float | None = None) -> dict:
    """:func:`traced_run` of the scene at ``scene_path`` in a process of its own (so one run's
    figures, its peak RSS above all, are not another's), streamed to ``store`` in chunks of
    ``chunk`` records if given, its RSS read every ``rss_every`` s of simulated time if given
    (:class:`RssTrace`, printed to this process's stderr as it goes).  Returns its figures with
    the run's ``events``, ``samples``, ``segments``, ``steps`` and ``rss_trace`` ([t, kB] pairs)."""
    import json
    import subprocess
    spec = dict(scene=str(scene_path), t_end=t_end, store=None if store is None else str(store), chunk=chunk,
                traced=traced, rss_every=rss_every)
    out = subprocess.run([sys.executable, __file__, "traced-run", json.dumps(spec)], stdout=subprocess.PIPE,
                         stderr=None if rss_every else subprocess.PIPE, text=True)
    if out.returncode:
        sys.exit(f"the run of {scene_path} to t = {t_end:g} s failed:\n{out.stderr or '(its stderr above)'}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _traced_run_child(spec: dict) -> dict:
    import pcmm
    from pcmm.results.store import StoreWriter
    store = None
    if spec["store"] is not None:
        store = StoreWriter(spec["store"], **({} if spec["chunk"] is None else dict(chunk_records=spec["chunk"])))
    trace = RssTrace(spec["rss_every"]) if spec.get("rss_every") else None
    kw = {} if trace is None else dict(progress=trace)
    traj, figures = traced_run(pcmm.load_scene(spec["scene"]), spec["t_end"], traced=spec["traced"], store=store, **kw)
    return dict(figures, events=len(traj.events), samples=sum(len(s.t) for s in traj.segments),
                segments=len(traj.segments), steps=traj.stats["steps"],
                rss_trace=[] if trace is None else trace.points)


if __name__ == "__main__" and sys.argv[1:2] == ["traced-run"]:
    import json
    print(json.dumps(_traced_run_child(json.loads(sys.argv[2]))))
