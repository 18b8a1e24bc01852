"""Per-run isolation of a study (issue 25, item 2): a run that crashes its worker or hangs is a
row and the sweep goes on; --resume retries such rows only with --retry-failed; workers die with
the sweep (kill -9 leaves no orphan); each worker builds a model once for all its runs."""
from __future__ import annotations

import csv
import signal
import time
from pathlib import Path

import pytest

import pcmm
from pcmm.studies.sweep import Axis, make_plan, sweep

from builders import EXAMPLES
from processes import Gate, held_cli

THREE_BAR = EXAMPLES / "three_bar.toml"


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow  # waits out a hanging run
def test_a_crashing_and_a_hanging_run_are_rows_and_the_sweep_goes_on(tmp_path):
    import study_hooks
    plan = make_plan([Axis("forces.tau1.value", (1.955, 3.0, 4.0, 2.1))])
    out = tmp_path / "r.csv"
    t0 = time.monotonic()
    res = sweep(pcmm.load_scene(THREE_BAR), plan, out, pcmm.RunOptions(t_end=0.2), workers=2, run_timeout=5.0,
                worker_init="study_hooks:faulty")
    took = time.monotonic() - t0
    rows = {r["forces.tau1.value"]: r for r in read(out)}
    assert res.status == {"complete": 2, "crashed": 1, "timeout": 1}
    assert rows["3.0"]["status"] == "crashed"
    assert "died of SIGABRT (aborted: a crash in native code)" in rows["3.0"]["error"]
    assert rows["4.0"]["status"] == "timeout" and "time limit of 5 s" in rows["4.0"]["error"]
    # stopped at its limit, not for ever (the hang is an hour; the bound on the whole sweep leaves
    # room for four worker start-ups, 1.5 s of CPU each, on a loaded machine)
    assert 5.0 <= float(rows["4.0"]["wall_s"]) < 30 and took < study_hooks.HANG_S / 6
    assert rows["1.955"]["status"] == rows["2.1"]["status"] == "complete"
    # the paper's latch time (Table 1) from a worker that replaced a crashed one
    assert float(rows["1.955"]["first_impact_t"]) == pytest.approx(0.1672851, abs=1e-7)

    # --resume keeps the failed rows; --retry-failed runs them again (here: without the fault)
    res = sweep(pcmm.load_scene(THREE_BAR), plan, out, pcmm.RunOptions(t_end=0.2), workers=2, resume=True)
    assert (res.skipped, res.ran) == (4, 0)
    res = sweep(pcmm.load_scene(THREE_BAR), plan, out, pcmm.RunOptions(t_end=0.2), workers=2, resume=True,
                retry_failed=True)
    assert (res.skipped, res.ran, res.retried) == (2, 2, 2) and res.status == {"complete": 4}
    rows = read(out)
    assert len(rows) == 4 and sorted(r["forces.tau1.value"] for r in rows) == ["1.955", "2.1", "3.0", "4.0"]


def test_each_worker_builds_each_model_once(tmp_path, monkeypatch):
    # Example 1 has two configurations; 12 runs that all latch (both models used) on 2 workers
    log = tmp_path / "builds.txt"
    monkeypatch.setenv("PCMM_TEST_BUILDS", str(log))
    plan = make_plan([Axis("forces.tau3.value", tuple(0.23 + 0.005 * i for i in range(12)))])
    res = sweep(pcmm.load_scene(THREE_BAR), plan, tmp_path / "r.csv", pcmm.RunOptions(t_end=0.2), workers=2,
                worker_init="study_hooks:count_builds")
    assert res.status == {"complete": 12}
    assert all(int(r["events"]) == 1 for r in read(tmp_path / "r.csv"))  # config2 reached in every run
    builds = log.read_text().split()
    per_worker = {pid: builds.count(pid) for pid in set(builds)}
    assert set(per_worker.values()) == {2} and len(per_worker) <= 2  # 2 models per worker, not 2 per run


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        try:
            kids = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except FileNotFoundError:
            continue
        out += [int(k) for k in kids]
        todo += [int(k) for k in kids]
    return out


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux's /proc")
@pytest.mark.slow  # a sweep killed in a subprocess
def test_kill_9_of_the_sweep_leaves_no_worker_behind(tmp_path):
    gate = Gate(tmp_path / "gate", rows=2)
    proc = held_cli(["sweep", str(THREE_BAR), "--set", "forces.tau1.value=1.9:2.1:40", "--t-end", "3.0", "--out",
                     "r.csv", "--workers", "2", "--quiet"], gate, cwd=tmp_path)
    assert gate.wait_held(proc) == 2  # the sweep waits mid-way (38 runs left), its workers alive
    kids = _descendants(proc.pid)
    assert len(kids) >= 2  # the two workers (and nothing of multiprocessing's)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    t0 = time.time()
    while time.time() - t0 < 10 and any(_alive(k) for k in kids):
        time.sleep(0.05)
    assert [k for k in kids if _alive(k)] == []


@pytest.mark.slow  # a Dask cluster; waits out a 5 s limit and 3 s runs
def test_on_dask_a_crashing_and_a_hanging_run_are_rows_too_and_a_time_limit_counts_from_the_runs_start(tmp_path):
    """A run that kills its Dask worker is a crashed row, one that hangs a timeout row once it has
    run for its time limit (5 s), the others complete.  Then three runs of study_hooks.SLOW_S = 3 s
    on the two workers: the third waits 3 s for a worker, so it ends 6 s after its submission but
    3 s after its start, and completes (a limit counted from submission stopped it at 5 s).  Each
    slow run lasts 3 s on any machine (it runs, then waits out the rest): 2 s are left for Dask to
    report it, and 1 s between a limit counted from the start and one counted from submission."""
    distributed = pytest.importorskip("distributed")
    import dask
    from distributed.diagnostics.plugin import WorkerPlugin
    import study_hooks

    class Faulty(study_hooks.FaultyPlugin, WorkerPlugin):  # its setup first
        pass
    plan = make_plan([Axis("forces.tau1.value", (1.955, 3.0, 4.0))])
    slow = make_plan([Axis("forces.tau1.value", (5.0,)), Axis("forces.tau3.value", (0.23, 0.235, 0.24))])
    limit = 5.0
    assert study_hooks.SLOW_S < limit < 2 * study_hooks.SLOW_S
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster:
            with distributed.Client(cluster) as client:
                client.register_plugin(Faulty())
            res = sweep(pcmm.load_scene(THREE_BAR), plan, tmp_path / "r.csv", pcmm.RunOptions(t_end=0.2),
                        scheduler=cluster.scheduler_address, run_timeout=limit)
            t0 = time.monotonic()
            res_slow = sweep(pcmm.load_scene(THREE_BAR), slow, tmp_path / "slow.csv", pcmm.RunOptions(t_end=0.2),
                             scheduler=cluster.scheduler_address, run_timeout=limit)
            took = time.monotonic() - t0
    rows = {r["forces.tau1.value"]: r for r in read(tmp_path / "r.csv")}
    assert res.status == {"complete": 1, "crashed": 1, "timeout": 1}
    assert rows["3.0"]["status"] == "crashed" and "the Dask cluster lost the run" in rows["3.0"]["error"]
    assert rows["4.0"]["status"] == "timeout" and "time limit of 5 s" in rows["4.0"]["error"]
    assert limit <= float(rows["4.0"]["wall_s"]) < 4 * limit  # stopped at its limit, counted from its start
    assert float(rows["1.955"]["first_impact_t"]) == pytest.approx(0.1672851, abs=1e-7)
    # the slow runs: all complete, and the last one had to wait for a worker
    assert res_slow.status == {"complete": 3}, read(tmp_path / "slow.csv")
    assert all(float(r["wall_s"]) >= study_hooks.SLOW_S for r in read(tmp_path / "slow.csv"))
    assert took >= 2 * study_hooks.SLOW_S > limit
