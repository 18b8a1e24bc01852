"""``pcmm optimize`` (issue 25, item 3): the optimum of a scene known in closed form, found to the
method's tolerance by COBYQA (one run at a time) and by differential evolution (generations in
parallel on the pool and on Dask); every evaluation a row of the study table; a resume after
SIGKILL replays the table with no row lost or run twice."""
from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import pcmm
from pcmm.errors import UsageError
from pcmm.studies.optimize import Constraint, optimize, parse_constraint, parse_vary
from pcmm.studies.plan import Axis

from processes import Gate, held_cli
from study_scenes import I_PIVOT, SWING, strike, torque_to_stop

ROOT = Path(__file__).resolve().parents[1]
T_MAX = 0.5  # the strike must come by 0.5 s
BOX = Axis("forces.drive.value", low=0.5, high=5.0)
# the impulse grows with the torque and the strike time falls with it: the least impulse that
# strikes by T_MAX is at the torque that strikes at T_MAX exactly, 2 I SWING / T_MAX^2 (by hand)
TAU_STAR = 2 * I_PIVOT * SWING / T_MAX ** 2
LIMIT = Constraint("first_impact_t", "<=", T_MAX)


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return torque_to_stop(tmp_path_factory.mktemp("scene"))


def test_the_scene_is_the_hand_derivation(scene):
    for torque in (0.7, TAU_STAR):
        traj = pcmm.simulate(pcmm.load_scene(scene).with_values({"forces.drive.value": torque}))
        t, p = strike(torque)
        assert traj.events[0]["t"] == pytest.approx(t, rel=1e-9)
        assert abs(traj.events[0]["impulse"]["normal"]) == pytest.approx(p, rel=1e-9)


def test_cobyqa_finds_the_least_impulse_that_strikes_in_time(scene, tmp_path):
    res = optimize(pcmm.load_scene(scene), [BOX], "peak_impulse", tmp_path / "o.csv", subject_to=[LIMIT],
                   method="cobyqa", tol=1e-6)
    tau = res.x[BOX.path]
    # to COBYQA's final trust-region radius (1e-6 of the box) - and feasible: at or above TAU_STAR
    assert TAU_STAR - 1e-9 <= tau <= TAU_STAR + 10 * 1e-6 * (BOX.high - BOX.low)
    assert res.value == pytest.approx(strike(TAU_STAR)[1], rel=1e-5)
    rows = read(tmp_path / "o.csv")
    assert len(rows) == res.ran == res.evaluations and res.replayed == 0  # every evaluation is a row
    assert [int(r["run"]) for r in rows] == list(range(len(rows)))
    assert rows[res.run][BOX.path] == repr(tau)


@pytest.mark.slow  # generations on the pool
def test_differential_evolution_on_the_pool(scene, tmp_path):
    res = optimize(pcmm.load_scene(scene), [BOX], "peak_impulse", tmp_path / "pool.csv", subject_to=[LIMIT],
                   method="de", max_evals=100, tol=1e-3, workers=2, seed=3)
    assert res.x[BOX.path] == pytest.approx(TAU_STAR, rel=2e-3) and res.x[BOX.path] >= TAU_STAR
    assert len(read(tmp_path / "pool.csv")) == res.ran


DE_SHORT = 24  # the initial population (8) and two generations: what the Dask backend is compared on


@pytest.mark.slow  # generations on the pool and on a Dask cluster
def test_differential_evolution_on_dask_is_the_pools(scene, tmp_path):
    """The same seed asks for the same runs wherever they run, and they give the same numbers: the
    first generations on a Dask cluster and on the pool (DE's generations do not depend on its
    budget, which only stops it: these are the first rows of the converging run above)."""
    res = optimize(pcmm.load_scene(scene), [BOX], "peak_impulse", tmp_path / "pool.csv", subject_to=[LIMIT],
                   method="de", max_evals=DE_SHORT, tol=1e-3, workers=2, seed=3)
    assert len(read(tmp_path / "pool.csv")) == res.ran == DE_SHORT
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        on_dask = optimize(pcmm.load_scene(scene), [BOX], "peak_impulse", tmp_path / "dask.csv", subject_to=[LIMIT],
                           method="de", max_evals=DE_SHORT, tol=1e-3, scheduler=c.scheduler_address, seed=3)
    assert on_dask.x == res.x and on_dask.value == res.value
    strip = lambda rows: sorted(({k: v for k, v in r.items() if k not in ("solve_s", "wall_s", "check")}  # noqa: E731
                                 for r in rows), key=lambda r: int(r["run"]))  # rows land as runs finish
    assert strip(read(tmp_path / "dask.csv")) == strip(read(tmp_path / "pool.csv"))


def _optimize_cli(args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "pcmm.cli", "optimize", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow  # an optimisation killed and resumed in subprocesses
def test_resume_after_kill_9_replays_the_table(scene, tmp_path):
    args = [str(scene), "--vary", f"{BOX.path}={BOX.low}:{BOX.high}", "--minimize", "peak_impulse",
            "--subject-to", f"first_impact_t<={T_MAX}", "--out", "o.csv", "--max-evals", "40", "--tol", "1e-9"]
    whole = _optimize_cli([*args[:-6], "--out", "whole.csv", *args[-4:]], tmp_path)
    assert whole.wait(timeout=300) == 0
    reference = read(tmp_path / "whole.csv")
    gate = Gate(tmp_path / "gate", rows=5)
    proc = held_cli(["optimize", *args], gate, cwd=tmp_path)
    out = tmp_path / "o.csv"
    assert gate.wait_held(proc) == 5  # it waits mid-way: the kill comes before its end for certain
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    kept = len(read(out))
    assert 5 <= kept < len(reference)
    again = _optimize_cli([*args, "--resume"], tmp_path)
    stdout, err = again.communicate(timeout=300)
    assert again.returncode == 0, err
    rows = read(out)
    # each run once, in the uninterrupted order, with the uninterrupted values
    assert [r[BOX.path] for r in rows] == [r[BOX.path] for r in reference]
    assert [r["run"] for r in rows] == [str(i) for i in range(len(rows))]
    assert f"read from o.csv, {len(reference) - kept} run" in stdout and f"{kept} read" not in err


def test_bad_boxes_and_bounds_are_messages():
    with pytest.raises(UsageError, match="give PATH=LOW:HIGH"):
        parse_vary("forces.drive.value=1,2")
    with pytest.raises(UsageError, match="OUTPUT<=VALUE"):
        parse_constraint("first_impact_t<0.5")
    assert parse_constraint("first_impact_t >= 0.25") == Constraint("first_impact_t", ">=", 0.25)
