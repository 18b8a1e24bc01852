"""Design studies (pcmm.studies.sweep, ``pcmm sweep``).

Every run's numbers are checked against the same scene run one by one in this
process, built by another route (``dataclasses.replace`` on the loaded scene) and
reduced by hand from the trajectory; on the local process pool and on a real
Dask ``LocalCluster``.  A sweep killed midway and resumed has each run once.
"""
from __future__ import annotations

import csv
import dataclasses
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import suite_checks
from processes import Gate, held_cli

import pcmm
from pcmm.errors import SceneError, UsageError
from pcmm.studies.sweep import (QUANTITIES, Axis, Plan, ResultsTable, check_collect, collect_value, columns, make_plan,
                        parse_set, quantities, read_plan_file, sweep)

from builders import EXAMPLES

ROOT = Path(__file__).resolve().parents[1]
THREE_BAR = EXAMPLES / "three_bar.toml"
STOP = EXAMPLES / "three_bar_stop.toml"
T_END = 0.2
TAU1 = (1.955, 2.5)
TAU3 = (0.1, 0.23)


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def one_by_one(tau1: float, tau3: float) -> dict:
    """The run of a variation, built with dataclasses.replace and reduced here by hand."""
    scene = pcmm.load_scene(THREE_BAR)
    f = scene.forces
    scene = dataclasses.replace(scene, forces=(dataclasses.replace(f[0], value=tau1), f[1],
                                               dataclasses.replace(f[2], value=tau3)))
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=T_END))
    ev = traj.events
    return {"events": len(ev), "first_impact_t": ev[0]["t"] if ev else None,
            "first_impulse": ev[0]["impulse"]["normal"] if ev else None,
            "kinetic_energy_lost": ev[0]["kinetic_energy_before"] - ev[0]["kinetic_energy_after"] if ev else 0.0,
            "configuration_final": traj.segments[-1].configuration,
            "max_holding": float(np.nanmax(np.abs(traj.series("constraint_forces", "O3.hold")))) if ev else None,
            "theta3": float(traj.segments[-1].theta[-1][traj.segments[-1].links.index("link3")])}


@pytest.fixture(scope="module")
def reference():
    return {(a, b): one_by_one(a, b) for a in TAU1 for b in TAU3}


def grid():
    return make_plan([Axis("forces.tau1.value", TAU1), Axis("forces.tau3.value", TAU3)])


def assert_rows_match(rows, reference):
    assert len(rows) == len(reference)
    seen = set()
    for r in rows:
        key = (float(r["forces.tau1.value"]), float(r["forces.tau3.value"]))
        seen.add(key)
        ref = reference[key]
        assert r["status"] == "complete" and r["error"] == ""
        assert int(r["events"]) == ref["events"]
        assert r["configuration_final"] == ref["configuration_final"]
        assert float(r["final.theta.link3"]) == ref["theta3"]
        if ref["events"]:
            assert float(r["first_impact_t"]) == ref["first_impact_t"]
            assert float(r["first_impulse"]) == ref["first_impulse"]
            assert float(r["peak_impulse"]) == abs(ref["first_impulse"]) == float(r["total_impulse"])
            assert float(r["kinetic_energy_lost"]) == ref["kinetic_energy_lost"]
            assert float(r["max_holding_force"]) == ref["max_holding"] > 0  # the latch's holding moment
        else:
            assert r["first_impact_t"] == "" and float(r["peak_impulse"]) == 0.0
            assert r["max_holding_force"] == ""  # nothing locked
        assert 0 < float(r["solve_s"]) < float(r["wall_s"])
    assert seen == set(reference)


def test_reference_grid_has_latches_and_misses(reference):
    # the grid holds both outcomes: the paper's scene latches at t_p = 0.1672851 s (README, Table 1)
    # before t_end; with the O3 preload cut to 0.1 N m, O3 does not reach pi by then
    assert reference[(1.955, 0.23)]["events"] == 1
    assert reference[(1.955, 0.23)]["first_impact_t"] == pytest.approx(0.1672851, abs=1e-7)
    assert reference[(1.955, 0.1)]["events"] == reference[(2.5, 0.1)]["events"] == 0
    assert reference[(2.5, 0.23)]["events"] == 0  # a stronger motor delays the latch past t_end


def test_pool_gives_the_one_by_one_numbers(tmp_path, reference):
    out = tmp_path / "pool.csv"
    res = sweep(pcmm.load_scene(THREE_BAR), grid(), out, pcmm.RunOptions(t_end=T_END),
                collect=["final.theta.link3"], workers=2)
    assert (res.planned, res.skipped, res.ran, res.status) == (4, 0, 4, {"complete": 4})
    rows = read(out)
    assert list(rows[0]) == columns(grid().paths, ["final.theta.link3"])
    assert_rows_match(rows, reference)


def test_serial_gives_the_one_by_one_numbers(tmp_path, reference):
    out = tmp_path / "serial.csv"
    sweep(pcmm.load_scene(THREE_BAR), grid(), out, pcmm.RunOptions(t_end=T_END),
          collect=["final.theta.link3"], workers=1)
    assert_rows_match(read(out), reference)


@pytest.mark.slow  # starts a Dask LocalCluster
def test_dask_local_cluster_gives_the_one_by_one_numbers(tmp_path, reference):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        out = tmp_path / "dask.csv"
        res = sweep(pcmm.load_scene(THREE_BAR), grid(), out, pcmm.RunOptions(t_end=T_END),
                    collect=["final.theta.link3"], scheduler=cluster.scheduler_address)
    assert res.status == {"complete": 4}
    assert_rows_match(read(out), reference)


def test_bad_path_or_value_fails_before_any_run(tmp_path):
    scene = pcmm.load_scene(STOP)
    out = tmp_path / "r.csv"
    plan = make_plan([Axis("forces.tau1.value", (1.0, 2.0)), Axis("transitions.O3 stop.restitution", (0.5, 1.5))])
    with pytest.raises(SceneError) as info:
        sweep(scene, plan, out, workers=1)
    assert info.value.problems == [f"--set transitions.O3 stop.restitution = 1.5: {STOP}: "
                                   "transitions[0] (O3 stop).restitution: = 1.5: must be in [0, 1]"]
    with pytest.raises(SceneError) as info:
        sweep(scene, make_plan([Axis("forces.tau4.value", (1.0,))]), out, workers=1)
    assert "value path 'forces.tau4.value': no element named 'tau4' in forces; closest: " in info.value.text()
    assert "'tau1'" in info.value.text()
    assert not out.exists()  # nothing ran, nothing written


def test_cli_bad_value_exit_2_and_nothing_written(tmp_path, capsys):
    from pcmm.cli import main
    out = tmp_path / "r.csv"
    code = main(["sweep", str(THREE_BAR), "--set", "forces.tau1.c=0.01,-1", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "forces.tau1.c = -1" in err and "forces[0] (tau1).c: = -1: must be >= 0" in err
    assert not out.exists()


def test_failed_and_partial_runs_are_rows(tmp_path, monkeypatch):
    sim = sys.modules["pcmm.run.loop"]
    real = sim.simulate

    def flaky(scene, options=pcmm.RunOptions(), progress=None):
        if scene.forces[0].value == 3.0:
            raise RuntimeError("a defect")
        return real(scene, options, progress)
    monkeypatch.setattr(sim, "simulate", flaky)
    out = tmp_path / "r.csv"
    plan = make_plan([Axis("solver.max_steps", (5, 1_000_000)), Axis("forces.tau1.value", (1.955, 3.0))])
    res = sweep(pcmm.load_scene(THREE_BAR), plan, out, pcmm.RunOptions(t_end=0.05), workers=1)
    rows = {(r["solver.max_steps"], r["forces.tau1.value"]): r for r in read(out)}
    assert res.status == {"partial": 1, "failed": 2, "complete": 1}
    assert rows[("5", "1.955")]["status"] == "partial" and "max_steps" in rows[("5", "1.955")]["error"]
    assert 0 < float(rows[("5", "1.955")]["t_final"]) < 0.05  # the partial run's own quantities are kept
    assert rows[("5", "3.0")]["status"] == "failed" and "RuntimeError: a defect" in rows[("5", "3.0")]["error"]
    assert rows[("5", "3.0")]["events"] == "" and float(rows[("5", "3.0")]["wall_s"]) > 0
    assert rows[("1000000", "1.955")]["status"] == "complete"
    assert float(rows[("1000000", "1.955")]["t_final"]) == 0.05


def _spawn(args, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "pcmm.cli", "sweep", *args], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=suite_checks.default_signals)


@pytest.mark.parametrize("sig, workers", [(signal.SIGTERM, "1"), (signal.SIGINT, "2")])
@pytest.mark.slow  # two 16-run sweeps in subprocesses, one signalled
def test_killed_sweep_resumes_to_the_complete_table(tmp_path, sig, workers):
    # 16 runs of Example 1 to 3 s; the sweep waits after its second row (a gate, processes.py)
    # and the signal lands there, with 14 runs still to run, however fast they are
    args = [str(THREE_BAR), "--set", "forces.tau1.value=1.9:2.1:4", "--set", "forces.tau3.value=0.25:0.4:4",
            "--t-end", "3.0", "--out", "r.csv", "--workers", workers]
    out = tmp_path / "r.csv"
    gate = Gate(tmp_path / "gate", rows=2)
    proc = held_cli(["sweep", *args], gate, cwd=tmp_path, preexec_fn=suite_checks.default_signals)
    assert gate.wait_held(proc) == 2
    proc.send_signal(sig)
    gate.open()  # (a signal held until the wait ends stops it all the same)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig and "--resume" in err  # 143 for SIGTERM, 130 for Ctrl-C
    first = read(out)
    assert 2 <= len(first) < 16
    assert all(r["status"] == "complete" for r in first)  # a run cut short by the signal is not a row
    proc = _spawn([*args[:-2], "--workers", "1", "--resume", "--quiet"], tmp_path)
    stdout, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert f"16 runs planned, {len(first)} already in r.csv, {16 - len(first)} run" in stdout
    rows = read(out)
    keys = [(r["forces.tau1.value"], r["forces.tau3.value"]) for r in rows]
    assert len(keys) == len(set(keys)) == 16  # each run once
    assert sorted(int(r["run"]) for r in rows) == list(range(16))
    assert rows[:len(first)] == first  # what was finished is kept as it was


def test_resume_drops_a_row_cut_short_and_rejects_another_sweep(tmp_path):
    scene = pcmm.load_scene(THREE_BAR)
    plan = make_plan([Axis("forces.tau3.value", (0.25, 0.3))])
    out = tmp_path / "r.csv"
    sweep(scene, plan, out, pcmm.RunOptions(t_end=0.05), workers=1)
    lines = out.read_text().splitlines(keepends=True)
    out.write_text("".join(lines[:2]) + lines[2][:17])  # killed while writing the second row
    res = sweep(scene, plan, out, pcmm.RunOptions(t_end=0.05), workers=1, resume=True)
    assert (res.skipped, res.ran) == (1, 1)
    assert [r["forces.tau3.value"] for r in read(out)] == ["0.25", "0.3"]
    with pytest.raises(UsageError, match="exists; pass --resume"):
        sweep(scene, plan, out, pcmm.RunOptions(t_end=0.05), workers=1)
    with pytest.raises(UsageError, match="made with another options"):
        sweep(scene, plan, out, pcmm.RunOptions(t_end=0.06), workers=1, resume=True)
    other = make_plan([Axis("forces.tau1.value", (2.0,))])
    with pytest.raises(UsageError, match="made with another paths"):
        sweep(scene, other, out, pcmm.RunOptions(t_end=0.05), workers=1, resume=True)
    (tmp_path / "r.csv.sweep.json").unlink()  # without its sidecar, the table's own columns say it
    with pytest.raises(UsageError, match="its columns \\(run, forces.tau3.value, status"):
        sweep(scene, other, out, pcmm.RunOptions(t_end=0.05), workers=1, resume=True)
    assert [r["forces.tau3.value"] for r in read(out)] == ["0.25", "0.3"]  # refused resumes change nothing


def test_grid_and_ranges():
    a = parse_set("forces.tau1.value=1.5:2.5:5")
    assert a.values == (1.5, 1.75, 2.0, 2.25, 2.5)
    assert parse_set("a=0.15:0.35:9").values[2] == 0.2  # the decimal meant, not 0.19999999999999998
    assert parse_set("solver.max_events=10:50:5").values == (10, 20, 30, 40, 50)  # integers stay integers
    assert parse_set("transitions.O3 stop.restitution = 0.2, 0.5").values == (0.2, 0.5)
    assert parse_set("solver.method=DOP853,RK45").values == ("DOP853", "RK45")
    plan = make_plan([Axis("a", (1, 2, 3)), Axis("b", ("x", "y"))])
    assert plan.runs == ((1, "x"), (1, "y"), (2, "x"), (2, "y"), (3, "x"), (3, "y"))
    for bad, words in [("x", "PATH=VALUES"), ("a=1,1", "given twice"), ("a=1:2:0", "count >= 1"),
                       ("a=2:1", "low < high"), ("a=1:2:3:4", "start:stop:count"), ("a=x:2:3", "with numbers")]:
        with pytest.raises(UsageError, match=words):
            make_plan([parse_set(bad)], "random", 3, 1) if bad == "a=2:1" else parse_set(bad)


def test_latin_hypercube_and_random_samples():
    axes = [parse_set("a=0:10"), parse_set("b=-1:1")]
    lhs = make_plan(axes, "lhs", 8, seed=3)
    pts = np.array(lhs.runs)
    # Latin hypercube: in each dimension, every one of the 8 equal strata holds exactly one sample
    assert sorted(np.floor((pts[:, 0] - 0) / 10 * 8).astype(int)) == list(range(8))
    assert sorted(np.floor((pts[:, 1] + 1) / 2 * 8).astype(int)) == list(range(8))
    assert make_plan(axes, "lhs", 8, seed=3) == lhs != make_plan(axes, "lhs", 8, seed=4)  # reproducible by seed
    rnd = make_plan(axes, "random", 50, seed=1)
    x = np.array(rnd.runs)
    assert np.all((x[:, 0] >= 0) & (x[:, 0] < 10) & (x[:, 1] >= -1) & (x[:, 1] < 1))
    assert rnd == make_plan(axes, "random", 50, seed=1)
    with pytest.raises(UsageError, match="--seed"):
        make_plan(axes, "lhs", 8)
    with pytest.raises(UsageError, match="give low:high"):
        make_plan([Axis("a", (1, 2))], "random", 3, 1)


def test_plan_file(tmp_path):
    f = tmp_path / "study.toml"
    f.write_text('sample = "grid"\ncollect = ["final.t"]\nt_end = 0.2\n[set]\n"forces.tau3.value" = [0.2, 0.3]\n'
                 '"forces.tau1.value" = { start = 1.0, stop = 2.0, count = 3 }\n')
    p = read_plan_file(f)
    assert [a.values for a in p["axes"]] == [(0.2, 0.3), (1.0, 1.5, 2.0)]
    assert (p["sample"], p["collect"], p["t_end"]) == ("grid", ["final.t"], 0.2)
    f.write_text('sampel = "grid"\n[set]\n"a" = [1]\n')
    with pytest.raises(UsageError, match="sampel: unknown key \\(did you mean 'sample'\\?\\)"):
        read_plan_file(f)


def test_quantities_by_hand():
    ev = lambda t, P, k0, k1, impact=True, **kw: {"t": t, "impact": impact, "impulse": {"normal": P},  # noqa: E731
                                                  "kinetic_energy_before": k0, "kinetic_energy_after": k1, **kw}
    summ = {"events": [ev(0.5, 0.0, 1.0, 1.0, impact=False), ev(1.0, -0.3, 2.0, 1.5, energy_dissipated=0.6),
                       ev(1.1, 0.2, 1.5, 1.4, energy_dissipated=0.1, holding_force=[3.0, -7.5], merge=True)],
            "configuration_final": "c2", "final": {"t": 2.0},
            "stats": {"wall_s": 0.25, "holding": {"O3.hold": {"min": -7.5, "t_min": 9.0, "max": 3.0, "t_max": 1.0},
                                                  "stop": {"min": math.inf, "t_min": None, "max": 2.0, "t_max": 8.0}}}}
    q = quantities(summ)
    assert set(q) == set(QUANTITIES) - {"wall_s"}
    assert (q["events"], q["impacts"], q["first_impact_t"], q["first_impulse"]) == (3, 2, 1.0, -0.3)
    assert q["peak_impulse"] == 0.3 and q["total_impulse"] == pytest.approx(0.5, abs=1e-15)
    assert q["kinetic_energy_lost"] == pytest.approx(0.6, abs=1e-15)
    assert q["energy_dissipated"] == pytest.approx(0.7, abs=1e-15)
    assert q["max_holding_force"] == 7.5  # the largest magnitude, never a time (t_min = 9)
    assert q["last_merge_t"] == 1.1 and quantities({"events": [], "stats": {}})["last_merge_t"] is None
    assert (q["configuration_final"], q["t_final"], q["solve_s"]) == ("c2", 2.0, 0.25)
    assert quantities({"events": [], "stats": {}})["max_holding_force"] is None
    assert collect_value(summ, "events[-1].impulse.normal") == 0.2
    assert collect_value(summ, "events[1].holding_force") is None
    assert collect_value(summ, "events[2].holding_force") == "[3.0, -7.5]"
    assert collect_value(summ, "final.nothing") is None
    with pytest.raises(UsageError, match="did you mean 'final'"):
        check_collect(["finl.t"])


def test_scheduler_without_distributed_is_a_clear_message(tmp_path, monkeypatch, capsys):
    from pcmm.cli import main
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    out = tmp_path / "r.csv"
    code = main(["sweep", str(THREE_BAR), "--set", "forces.tau1.value=2.0", "--out", str(out),
                 "--scheduler", "local"])
    err = capsys.readouterr().err
    assert code == 2 and "--scheduler needs Dask's distributed package" in err and "pcmm[sweep]" in err
    assert not out.exists()


def test_figures_and_parquet(tmp_path):
    pytest.importorskip("matplotlib")
    from pcmm.studies.plots import numeric_columns, plot_sweep, read_rows
    out = tmp_path / "r.csv"
    plan = make_plan([Axis("forces.tau3.value", (0.25, 0.3)), Axis("forces.tau1.value", (1.9, 2.0))])
    res = sweep(pcmm.load_scene(THREE_BAR), plan, out, pcmm.RunOptions(t_end=0.2), collect=["stats.steps"],
                workers=1)
    numeric = [q for q in QUANTITIES if q != "configuration_final"] + ["stats.steps"]  # all four latch
    assert numeric_columns(read_rows(out), plan.paths) == numeric
    files = plot_sweep(out, plan.paths, tmp_path, quantities=["kinetic_energy_lost", "stats.steps"])
    assert sorted(f.name for f in files) == sorted(f"{q}__vs__{p}.png" for q in ("kinetic_energy_lost", "stats.steps")
                                                   for p in plan.paths)
    assert all(f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for f in files)
    try:
        import pyarrow.parquet as pq
    except ImportError:
        assert res.parquet is None
    else:
        t = pq.read_table(res.parquet)
        assert t.num_rows == 4 and t.column_names == columns(plan.paths, ["stats.steps"])
        rows = read(out)  # the same numbers as the CSV, typed
        assert t.column("forces.tau3.value").to_pylist() == [float(r["forces.tau3.value"]) for r in rows]
        assert t.column("kinetic_energy_lost").to_pylist() == [float(r["kinetic_energy_lost"]) for r in rows]
        assert t.column("stats.steps").to_pylist() == [int(r["stats.steps"]) for r in rows]
        assert t.column("status").to_pylist() == ["complete"] * 4


def test_results_table_identity_is_the_values_text(tmp_path):
    t = ResultsTable(tmp_path / "t.csv", columns(["a"], []), 1, resume=False, force=False)
    t.append({"run": 0, "a": 0.1 + 0.2, "status": "complete"})
    t.close()
    t = ResultsTable(tmp_path / "t.csv", columns(["a"], []), 1, resume=True, force=False)
    assert set(t.done) == {("0.30000000000000004",)}
    assert Plan(("a",), ((0.1 + 0.2,),)).key(0) in t.done and Plan(("a",), ((0.3,),)).key(0) not in t.done
    t.close()
    assert math.isclose(float(read(tmp_path / "t.csv")[0]["a"]), 0.3)


def test_shipped_study_file_is_the_readme_grid():
    p = read_plan_file(EXAMPLES / "studies" / "three_bar_latch.toml")
    from_file = make_plan(p["axes"], p["sample"], p.get("runs"), p.get("seed"))
    from_cli = make_plan([parse_set("forces.tau3.value=0.15:0.35:9"), parse_set("forces.tau1.value=1.7,1.955,2.2")])
    assert from_file == from_cli and len(from_file.runs) == 27 and p["collect"] == ["final.theta.link3"]
    committed = read(ROOT / "docs" / "figures" / "design_study" / "example1_latch.csv")  # the README's table
    assert [tuple(float(r[k]) for k in from_cli.paths) for r in sorted(committed, key=lambda r: int(r["run"]))] \
        == [tuple(float(v) for v in run) for run in from_cli.runs]
