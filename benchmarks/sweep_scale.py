"""A design study at scale: an N-row sweep of Example 1 (default 10,000) through ``pcmm sweep``.

Four sweeps of the same plan (Latin-hypercube samples of the motor torque tau1 in [1.8, 2.2] N m
and the O3 preload tau3 in [0.15, 0.35] N m, seed 1, Example 1's own t_end of 1 s):

1. the local pool (``--workers`` = the usable cores): wall time, runs/s, the peak resident memory
   of the sweep and its workers together (sampled every 0.2 s from /proc), the table's size;
2. a Dask cluster of separate processes (``dask scheduler`` and ``dask worker --nworkers W
   --nthreads 1`` started here): the same figures, the cluster's processes counted in the memory;
3. the local pool killed with SIGKILL at a random moment (uniform in 20-80 % of sweep 1's time),
   the survivors checked (workers left alive), then ``--resume``: rows lost (planned runs missing
   from the final table) and rows duplicated (runs with more than one row), and rows whose
   checksum failed on resume;
4. the rows of 1 and 2 compared (the same numbers, wherever they ran).

Regenerate: python benchmarks/sweep_scale.py [--runs 10000]   (writes docs/benchmarks/sweep_scale.md)
"""
from __future__ import annotations

import argparse
import csv
import os
import random
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
    out, todo = [pid], [pid]
    while todo:
        p = todo.pop()
        try:
            kids = [int(k) for k in Path(f"/proc/{p}/task/{p}/children").read_text().split()]
        except (FileNotFoundError, ProcessLookupError):
            continue
        out += kids
        todo += kids
    return out


def _rss(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except (FileNotFoundError, ProcessLookupError):
        pass
    return 0


def run_sweep(args: list[str], cwd: Path, extra_pids=(), kill_at_rows: int | None = None):
    """Run ``pcmm sweep`` (a subprocess); its wall time, the peak summed RSS of it, its
    descendants and ``extra_pids``; with ``kill_at_rows`` it is SIGKILLed once its table has that
    many rows (returns the pids of its tree at that moment too)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "pcmm.cli", "sweep", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak, tree = 0, []
    while proc.poll() is None:
        tree = _tree(proc.pid)
        peak = max(peak, sum(_rss(p) for p in [*tree, *extra_pids]))
        if kill_at_rows is not None and _lines(cwd / args[args.index("--out") + 1]) - 1 >= kill_at_rows:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            break
        time.sleep(0.05 if kill_at_rows is not None else 0.2)
    out, err = proc.communicate()
    return time.perf_counter() - t0, peak, proc.returncode, out, err, tree


def _lines(path: Path) -> int:
    try:
        with open(path, "rb") as f:
            return sum(1 for _ in f)
    except FileNotFoundError:
        return 0


def rows_of(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def kill_and_resume(base, d: Path, n: int) -> None:
    """Only the kill -9 and --resume measurement (a plan of n distinct runs: lost = n - distinct rows)."""
    at = int(random.Random().uniform(0.2, 0.8) * n)
    t0 = time.perf_counter()
    _, _, code, _, _, tree = run_sweep([*base, "--out", "killed.csv"], d, kill_at_rows=at)
    killed_after = time.perf_counter() - t0
    time.sleep(2)
    orphans = [p for p in tree[1:] if Path(f"/proc/{p}").exists()
               and Path(f"/proc/{p}/stat").read_text().split(") ")[-1][0] != "Z"]
    kept = len(rows_of(d / "killed.csv"))
    wall, _, code2, out, err, _ = run_sweep([*base, "--out", "killed.csv", "--resume"], d)
    assert code2 == 0, err
    keys = [tuple(r[k] for k in KEY) for r in rows_of(d / "killed.csv")]
    print(f"kill -9 once {at} rows were in, after {killed_after:.0f} s (exit {code}): {kept} rows kept, "
          f"{len(tree) - 1} workers, {len(orphans)} alive 2 s later; --resume {wall:.0f} s: "
          f"{out.splitlines()[0]}; lost {n - len(set(keys))}, duplicated {len(keys) - len(set(keys))}, "
          f"dropped by the checksum {err.count('cut short or altered')}", flush=True)


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
            return kill_and_resume(base, d, n)
        # 1. the local pool
        wall, peak, code, out, err, _ = run_sweep([*base, "--out", "pool.csv"], d)
        assert code == 0, err
        pool_rows = rows_of(d / "pool.csv")
        results["local pool"] = {"wall": wall, "peak": peak, "size": (d / "pool.csv").stat().st_size,
                                 "rows": len(pool_rows), "status": out.splitlines()[0]}
        print("pool", results["local pool"], flush=True)

        # 2. Dask, separate processes
        if not args.no_dask:
            port = free_port()
            dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
            env = {**os.environ, "PYTHONPATH": str(ROOT)}
            sched = subprocess.Popen([*dask, "--port", str(port), "--no-dashboard"], env=env,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            wk = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", f"tcp://127.0.0.1:{port}",
                                   "--nworkers", str(workers), "--nthreads", "1", "--no-dashboard"], env=env,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            try:
                time.sleep(8)  # the cluster up before the clock starts
                cluster = [sched.pid, *_tree(wk.pid)]
                wall, peak, code, out, err, _ = run_sweep([*base, "--out", "dask.csv", "--scheduler",
                                                          f"tcp://127.0.0.1:{port}"], d, extra_pids=cluster)
                assert code == 0, err
                dask_rows = rows_of(d / "dask.csv")
                results["Dask (scheduler + worker processes)"] = {
                    "wall": wall, "peak": peak, "size": (d / "dask.csv").stat().st_size, "rows": len(dask_rows),
                    "status": out.splitlines()[0]}
                strip = lambda rs: sorted((tuple((k, v) for k, v in r.items()  # noqa: E731
                                                 if k not in ("solve_s", "wall_s", "check")) for r in rs))
                results["Dask (scheduler + worker processes)"]["same"] = strip(dask_rows) == strip(pool_rows)
                print("dask", results["Dask (scheduler + worker processes)"], flush=True)
            finally:
                for p in (wk, sched):
                    p.terminate()
                    try:
                        p.wait(timeout=30)
                    except subprocess.TimeoutExpired:
                        p.kill()

        # 3. SIGKILL at a random moment (when a random 20-80 % of the rows are in), then --resume
        at = int(random.Random().uniform(0.2, 0.8) * n)
        _, _, code, _, _, tree = run_sweep([*base, "--out", "killed.csv"], d, kill_at_rows=at)
        time.sleep(2)
        orphans = [p for p in tree[1:] if Path(f"/proc/{p}").exists()
                   and Path(f"/proc/{p}/stat").read_text().split(") ")[-1][0] != "Z"]
        kept = len(rows_of(d / "killed.csv"))
        wall, _, code2, out, err, _ = run_sweep([*base, "--out", "killed.csv", "--resume"], d)
        assert code2 == 0, err
        final = rows_of(d / "killed.csv")
        keys = [tuple(r[k] for k in KEY) for r in final]
        planned = {tuple(r[k] for k in KEY) for r in pool_rows}
        results["kill -9 and --resume"] = {
            "at": at, "code": code, "kept": kept, "workers": len(tree) - 1, "orphans": len(orphans),
            "lost": len(planned - set(keys)), "duplicated": len(keys) - len(set(keys)),
            "dropped": err.count("cut short or altered"), "resume_wall": wall}
        print("kill", results["kill -9 and --resume"], flush=True)

    load_end = "%.2f %.2f %.2f" % os.getloadavg()
    table = []
    for name, r in results.items():
        if "wall" in r and "peak" in r:
            table.append([name, r["rows"], f"{r['wall']:.0f}", f"{r['rows'] / r['wall']:.1f}",
                          f"{r['peak'] / 2**20:.0f}", f"{r['size'] / 2**20:.2f}", f"{r['size'] / max(1, r['rows']):.0f}",
                          "yes" if r.get("same", True) else "NO"])
    k = results["kill -9 and --resume"]
    page = [
        f"# A design study at scale: {n:,} runs of Example 1", "",
        f"Regenerate: `{_common.command_line()}`", "",
        _common.machine_md(info) + f" Load average at the end: {load_end}.", "",
        f"The plan: {n:,} Latin-hypercube samples of tau1 in [1.8, 2.2] N m and tau3 in [0.15, 0.35] N m "
        "(seed 1), each run Example 1 to its t_end of 1 s, through `pcmm sweep` as a user runs it "
        f"({workers} workers). Memory is the peak of the summed resident sets of the sweep, its workers and "
        "(Dask) the scheduler and worker processes, sampled every 0.2 s.", "",
        _common.md_table(["backend", "rows", "wall, s", "runs/s", "peak memory, MiB", "table, MiB",
                          "bytes per row", "same rows as the pool"], table), "",
        f"Killed with SIGKILL once {k['at']:,} rows were in (exit {k['code']}), with {k['kept']:,} rows in the table and "
        f"{k['workers']} worker processes; {k['orphans']} of them alive 2 s later. `--resume` ran the rest in "
        f"{k['resume_wall']:.0f} s: rows lost {k['lost']}, rows duplicated {k['duplicated']}, rows dropped on "
        f"resume for a failed checksum {k['dropped']}.", "",
        f"Benchmark wall time: {time.perf_counter() - t_all:.0f} s.",
    ]
    out = _common.DOCS / ("sweep_scale.md" if n == 10_000 else f"sweep_scale_{n}.md")
    out.write_text("\n".join(page) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
