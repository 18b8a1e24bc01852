"""A design study at scale: an N-row sweep of Example 1 (default 10,000) through ``pcmm sweep``.

Four sweeps of the same plan (Latin-hypercube samples of the motor torque tau1 in [1.8, 2.2] N m
and the O3 preload tau3 in [0.15, 0.35] N m, seed 1, Example 1's own t_end of 1 s):

0. the cost of one row, in this process (CPU time, 200 runs after one warm-up): the varied scene
   built, ``pcmm.simulate``, the run summary (its recorded series derived: energies, holding
   forces), the row's quantities, the row written to a table;
1. the local pool (``--workers`` = the usable cores): wall time, runs/s (overall and steady, from
   the first row on), CPU time per row (the sweep and its workers: their rusage), the peak resident
   memory of the sweep and its workers together (sampled every 0.2 s from /proc) and its growth per
   row from a tenth of the rows to nine tenths, the table's size;
2. a Dask cluster of separate processes (``dask scheduler`` and ``dask worker --nworkers W
   --nthreads 1`` started here): the same figures, the cluster's processes counted in the memory
   and, from /proc, in the CPU time;
3. the local pool killed with SIGKILL at a random moment (uniform in 20-80 % of sweep 1's time),
   the survivors checked (workers left alive), then ``--resume``: rows lost (planned runs missing
   from the final table) and rows duplicated (runs with more than one row), and rows whose
   checksum failed on resume;
4. the rows of 1 and 2 compared (the same numbers, wherever they ran).

Regenerate: python benchmarks/sweep_scale.py [--runs 10000]   (writes docs/benchmarks/sweep_scale.md;
another --runs N writes docs/benchmarks/sweep_scale_N.md)
"""
from __future__ import annotations

import argparse
import csv
import os
import random
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import _common  # noqa: E402

SCENE = _common.EXAMPLES / "three_bar.toml"
SETS = ["--set", "forces.tau1.value=1.8:2.2", "--set", "forces.tau3.value=0.15:0.35", "--sample", "lhs",
        "--seed", "1"]
KEY = ("forces.tau1.value", "forces.tau3.value")


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (the children of every thread: a Dask nanny starts its worker
    process from another thread than its main one)."""
    out, todo = [pid], [pid]
    while todo:
        p = todo.pop()
        kids = []
        try:
            for task in Path(f"/proc/{p}/task").iterdir():
                try:
                    kids += [int(k) for k in (task / "children").read_text().split()]
                except (FileNotFoundError, ProcessLookupError):
                    continue
        except (FileNotFoundError, ProcessLookupError):
            continue
        kids = [k for k in dict.fromkeys(kids) if k not in out]
        out += kids
        todo += kids
    return out


def _spawned(pid: int) -> list[int]:
    """The processes under ``pid`` that multiprocessing spawned (a Dask nanny's worker processes)."""
    out = []
    for p in _tree(pid)[1:]:
        try:
            if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes():
                out.append(p)
        except (FileNotFoundError, ProcessLookupError):
            pass
    return out


def _rss(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except (FileNotFoundError, ProcessLookupError):
        pass
    return 0


def _cpu(pids) -> float:
    """CPU seconds (user + system) the processes ``pids`` have used so far (/proc/PID/stat)."""
    tick, total = os.sysconf("SC_CLK_TCK"), 0.0
    for p in pids:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(") ", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError, IndexError):
            continue
        total += (int(fields[11]) + int(fields[12])) / tick
    return total


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_sweep(args: list[str], cwd: Path, extra_pids=(), kill_at_rows: int | None = None, n: int | None = None):
    """Run ``pcmm sweep`` (a subprocess) and measure it: a dict of ``wall``, ``first_row`` (s
    from the start to the table's first row), ``cpu`` (the sweep and the workers it waited for,
    and the CPU the ``extra_pids`` used meanwhile), ``peak`` (the peak summed RSS of the sweep,
    its descendants and ``extra_pids``), ``rss_tenth`` and ``rss_ninth`` (that sum and the rows
    when a tenth, and nine tenths, of ``n`` rows were in), ``code``, ``out``, ``err``, ``tree`` (the pids of
    its tree at the last sample).  With ``kill_at_rows`` it is SIGKILLed once its table has that
    many rows."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out_path = cwd / args[args.index("--out") + 1]
    cpu0, extra0 = _children_cpu(), _cpu(extra_pids)
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "pcmm.cli", "sweep", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    m = {"peak": 0, "tree": [], "first_row": None, "rss_tenth": None, "rss_ninth": None}
    tenth, ninth = max(1, (n or 0) // 10), max(1, 9 * (n or 0) // 10)
    rows, last_count, lines = 0, 0.0, _LineCount(out_path)
    while proc.poll() is None:
        tree = _tree(proc.pid)
        rss = sum(_rss(p) for p in [*tree, *extra_pids])
        m["peak"], m["tree"] = max(m["peak"], rss), tree
        now = time.perf_counter()
        # the table's rows, counted while a figure still waits for them (at most every second)
        if kill_at_rows is not None or m["first_row"] is None or (n and m["rss_ninth"] is None and now - last_count >= 1.0):
            rows, last_count = lines() - 1, now
            if rows >= 1 and m["first_row"] is None:
                m["first_row"] = now - t0
            if n and rows >= tenth and m["rss_tenth"] is None:
                m["rss_tenth"] = (rss, rows)
            if n and rows >= ninth and m["rss_ninth"] is None and rows > m["rss_tenth"][1]:
                m["rss_ninth"] = (rss, rows)
        if kill_at_rows is not None and rows >= kill_at_rows:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            break
        time.sleep(0.05 if kill_at_rows is not None else 0.2)
    out, err = proc.communicate()
    m.update(wall=time.perf_counter() - t0, code=proc.returncode, out=out, err=err,
             cpu=_children_cpu() - cpu0 + _cpu(extra_pids) - extra0)
    return m


class _LineCount:
    """The lines of a growing file, counted from where the last count stopped (a table of 10,000
    rows is not read again 20 times a second while the sweep is timed)."""

    def __init__(self, path: Path):
        self.path, self.offset, self.lines = path, 0, 0

    def __call__(self) -> int:
        try:
            with open(self.path, "rb") as f:
                if os.fstat(f.fileno()).st_size < self.offset:  # started over (--force, a resume's rewrite)
                    self.offset, self.lines = 0, 0
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            return 0
        self.offset += len(data)
        self.lines += data.count(b"\n")
        return self.lines


def rows_of(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def kill_and_resume(base, d: Path, n: int) -> dict:
    """SIGKILL of a pool sweep once a random 20-80 % of its n rows are in, the survivors counted
    2 s later, then ``--resume``: rows lost (planned runs missing), duplicated, dropped on resume."""
    at = int(random.Random().uniform(0.2, 0.8) * n)
    k = run_sweep([*base, "--out", "killed.csv"], d, kill_at_rows=at)
    time.sleep(2)
    tree = k["tree"]
    orphans = [p for p in tree[1:] if Path(f"/proc/{p}").exists()
               and Path(f"/proc/{p}/stat").read_text().split(") ")[-1][0] != "Z"]
    kept = len(rows_of(d / "killed.csv"))
    r = run_sweep([*base, "--out", "killed.csv", "--resume"], d)
    assert r["code"] == 0, r["err"]
    keys = [tuple(row[c] for c in KEY) for row in rows_of(d / "killed.csv")]
    res = {"at": at, "code": k["code"], "killed_after": k["wall"], "kept": kept, "workers": len(tree) - 1,
           "orphans": len(orphans), "lost": n - len(set(keys)), "duplicated": len(keys) - len(set(keys)),
           "dropped": r["err"].count("cut short or altered"), "resume_wall": r["wall"],
           "resume_status": r["out"].splitlines()[0]}
    print("kill", res, flush=True)
    return res


def row_cost(runs: int = 200) -> dict:
    """CPU seconds per row of each step of a run of the sweep, in this process (one warm-up run
    first: the imports, the models): the varied scene, ``pcmm.simulate``, the run summary (the
    recorded series derived when first read), the row's quantities, the row written."""
    sys.path.insert(0, str(ROOT))
    import pcmm
    from pcmm.results.summary import summary
    from pcmm.studies.job import Job, _token, base_scene, quantities
    from pcmm.studies.plan import make_plan, parse_set
    from pcmm.studies.table import ResultsTable, columns
    scene = pcmm.load_scene(SCENE)
    plan = make_plan([parse_set(SETS[1]), parse_set(SETS[3])], "lhs", runs + 1, 1)
    raw, path = scene.source, str(scene.path)
    jobs = [Job(i, path, raw, _token(raw), plan.values(i), pcmm.RunOptions(), ()) for i in range(runs + 1)]
    steps = {"scene": 0.0, "simulate": 0.0, "summary": 0.0, "quantities": 0.0, "table": 0.0}
    with tempfile.TemporaryDirectory() as d:
        table = ResultsTable(Path(d) / "t.csv", columns(plan.paths, ()), len(plan.paths), False, False)
        try:
            for k, job in enumerate(jobs):
                c = [time.process_time()]
                sc = base_scene(job.scene_path, job.raw, job.token).with_values(job.values)
                c.append(time.process_time())
                traj = pcmm.simulate(sc, job.options)
                c.append(time.process_time())
                summ = summary(traj, sc.initial_configuration)
                c.append(time.process_time())
                row = {"run": job.index, **job.values, "status": "complete", "error": "", **quantities(summ)}
                c.append(time.process_time())
                table.append(row)
                c.append(time.process_time())
                if k:  # the first run is the warm-up
                    for name, a, b in zip(steps, c, c[1:]):
                        steps[name] += (b - a) / runs
        finally:
            table.close()
    print("row cost, CPU s per row", steps, flush=True)
    return steps


def _dask_cluster(workers: int):
    """A Dask scheduler and ``dask worker --nworkers W --nthreads 1``, separate processes."""
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    sched = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--port", str(port),
                              "--no-dashboard"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wk = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", f"tcp://127.0.0.1:{port}",
                           "--nworkers", str(workers), "--nthreads", "1", "--no-dashboard"], env=env,
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return f"tcp://127.0.0.1:{port}", sched, wk


def figures(m: dict, rows: list[dict], size: int, n: int) -> dict:
    """The page's figures of one measured sweep."""
    steady = (len(rows) - 1) / (m["wall"] - m["first_row"]) if m["first_row"] and len(rows) > 1 else float("nan")
    growth = None
    if m["rss_tenth"] is not None and m["rss_ninth"] is not None:
        growth = (m["rss_ninth"][0] - m["rss_tenth"][0]) / (m["rss_ninth"][1] - m["rss_tenth"][1])
    return {"rows": len(rows), "wall": m["wall"], "first_row": m["first_row"], "steady": steady,
            "cpu": m["cpu"], "peak": m["peak"], "growth": growth, "size": size,
            "in_worker": sum(float(r["wall_s"]) for r in rows) / max(1, len(rows)),
            "solve": sum(float(r["solve_s"] or 0) for r in rows) / max(1, len(rows)),
            "status": m["out"].splitlines()[0] if m["out"] else ""}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--kill-only", action="store_true", help="only the SIGKILL-and-resume measurement")
    args = ap.parse_args()
    info = _common.machine()
    workers = info["usable_cores"] or 1
    n = args.runs
    results: dict[str, dict] = {}
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        base = [str(SCENE), *SETS, "--runs", str(n), "--workers", str(workers), "--quiet"]
        if args.kill_only:
            kill_and_resume(base, d, n)
            return
        cost = row_cost()

        # 1. the local pool
        m = run_sweep([*base, "--out", "pool.csv"], d, n=n)
        assert m["code"] == 0, m["err"]
        pool_rows = rows_of(d / "pool.csv")
        results["local pool"] = figures(m, pool_rows, (d / "pool.csv").stat().st_size, n)
        print("pool", results["local pool"], flush=True)

        # 2. Dask, separate processes
        if not args.no_dask:
            address, sched, wk = _dask_cluster(workers)
            try:
                # the cluster up before the clock starts: the W worker processes its nannies spawn
                # (multiprocessing's spawn_main), then time for their imports
                t_up = time.perf_counter()
                while len(_spawned(wk.pid)) < workers and time.perf_counter() - t_up < 120:
                    time.sleep(0.5)
                time.sleep(8)
                cluster = [sched.pid, *_tree(wk.pid)]
                c0, t_idle = _cpu(cluster), time.perf_counter()
                time.sleep(5)  # and its CPU when idle (heartbeats, event loops): a rate over the sweep's time
                idle_rate = (_cpu(cluster) - c0) / (time.perf_counter() - t_idle)
                m = run_sweep([*base, "--out", "dask.csv", "--scheduler", address], d, extra_pids=cluster, n=n)
                assert m["code"] == 0, m["err"]
                dask_rows = rows_of(d / "dask.csv")
                name = "Dask (scheduler + worker processes)"
                results[name] = figures(m, dask_rows, (d / "dask.csv").stat().st_size, n)
                results[name]["idle_cpu"] = idle_rate * m["wall"]
                strip = lambda rs: sorted((tuple((k, v) for k, v in r.items()  # noqa: E731
                                                 if k not in ("solve_s", "wall_s", "check")) for r in rs))
                results[name]["same"] = strip(dask_rows) == strip(pool_rows)
                print("dask", results[name], flush=True)
            finally:
                for p in (wk, sched):
                    p.terminate()
                    try:
                        p.wait(timeout=30)
                    except subprocess.TimeoutExpired:
                        p.kill()

        # 3. SIGKILL at a random moment (when a random 20-80 % of the rows are in), then --resume
        k = kill_and_resume(base, d, n)

    load_end = "%.2f %.2f %.2f" % os.getloadavg()
    ms = lambda x: "—" if x is None or x != x else f"{1e3 * x:.1f}"  # noqa: E731
    table = []
    for name, r in results.items():
        table.append([name, f"{r['rows']:,}", f"{r['wall']:.0f}", ("—" if r["first_row"] is None else f"{r['first_row']:.1f}"), f"{r['rows'] / r['wall']:.1f}",
                      f"{r['steady']:.1f}", f"{100 * r['steady'] * r['in_worker'] / workers:.0f}",
                      ms(r["cpu"] / r["rows"]), ms(r["in_worker"]), ms(r["solve"]),
                      f"{r['peak'] / 2**20:.0f}", "—" if r["growth"] is None else f"{r['growth'] / 1024:.1f}",
                      f"{r['size'] / 2**20:.2f}", f"{r['size'] / max(1, r['rows']):.0f}",
                      "yes" if r.get("same", True) else "NO"])
    total = sum(cost.values())
    page = [
        f"# A design study at scale: {n:,} runs of Example 1", "",
        f"Regenerate: `{_common.command_line()}`", "",
        _common.machine_md(info) + f" Load average at the end: {load_end}.", "",
        f"The plan: {n:,} Latin-hypercube samples of tau1 in [1.8, 2.2] N m and tau3 in [0.15, 0.35] N m "
        "(seed 1), each run Example 1 to its t_end of 1 s, through `pcmm sweep` as a user runs it "
        f"({workers} workers).", "",
        "## What one row costs", "",
        "CPU time per row in one process (200 runs after a warm-up run), step by step:", "",
        _common.md_table(["step", "ms CPU per row", "share"],
                         [[name, ms(v), f"{100 * v / total:.0f} %"] for name, v in cost.items()]
                         + [["the row", ms(total), "100 %"]]), "",
        "`scene`: the varied scene built from the parsed base scene; `simulate`: `pcmm.simulate`; `summary`: "
        "the run summary, which derives the recorded series (energies, link positions, holding forces) of the "
        "segments it reads; `quantities`: the row's columns from the summary; `table`: the row's cells, "
        "checksum and write.", "",
        "## The sweep", "",
        _common.md_table(["backend", "rows", "wall, s", "first row, s", "runs/s", "runs/s from the first row",
                          "workers busy from the first row, %", "CPU per row, ms", "run in its worker, ms", "of which the solve, ms",
                          "peak memory, MiB", "memory growth per row, KiB", "table, MiB", "bytes per row",
                          "same rows as the pool"], table), "",
        "CPU per row: the sweep's process and the workers it waited for (their rusage), and for Dask the "
        "CPU the scheduler and worker processes used meanwhile (/proc), over the rows; it includes the "
        "start-up (imports, workers, the plan's validation)"
        + "".join(f"; of the {name}'s, {1e3 * r['idle_cpu'] / r['rows']:.1f} ms per row is the CPU its processes use "
                  "when idle (heartbeats, event loops: measured over 5 s before the sweep)"
                  for name, r in results.items() if "idle_cpu" in r) + ". Workers busy: the steady rate times the mean "
        "run in its worker, over the workers (the rest of their time they wait for the sweep, or the "
        "scheduler, to hand them a run). Run in its worker: the row's `wall_s` (scene, "
        "model, solve, summary), of which the solve: its `solve_s`. Memory: the peak of the summed resident "
        "sets of the sweep, its workers and (Dask) the scheduler and worker processes, sampled every 0.2 s; "
        "its growth per row from the moment a tenth of the rows were in to the moment nine tenths were.", "",
        f"Killed with SIGKILL once {k['at']:,} rows were in (exit {k['code']}, after {k['killed_after']:.0f} s), with "
        f"{k['kept']:,} rows in the table and {k['workers']} worker processes; {k['orphans']} of them alive 2 s "
        f"later. `--resume` ran the rest in {k['resume_wall']:.0f} s ({k['resume_status']}): rows lost "
        f"{k['lost']}, rows duplicated {k['duplicated']}, rows dropped on resume for a failed checksum "
        f"{k['dropped']}.", "",
        f"Benchmark wall time: {time.perf_counter() - t_all:.0f} s.",
    ]
    out = _common.DOCS / ("sweep_scale.md" if n == 10_000 else f"sweep_scale_{n}.md")
    out.write_text("\n".join(page) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
