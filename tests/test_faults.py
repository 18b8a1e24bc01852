"""Faults, hostile input and long runs (issue 14; item 8 of issue 13): one test per class of
defect, each failing on the behaviour before the fix.

The classes, by harm: an output the operating system refuses; SIGTERM and a second Ctrl-C;
silent replacement of files; CSV formulas; models Pinocchio rejects; tracebacks on hostile
input; hangs; silent wrong answers; misleading diagnoses; terminal hygiene.  The file-system
fault suite and the structural mutations are in ``test_fuzz.py``.
"""
from __future__ import annotations

import csv
import importlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import suite_checks
import builders
import processes
import pcmm
from pcmm.cli import main as cli_main
from pcmm.signals import Terminated

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def cli(args, capsys):
    rc = cli_main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return rc, out, err


def env():
    return {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def unwritable_folder(tmp_path: Path) -> Path:
    """A folder that exists but where no file can be created: a read-only folder (not for root,
    who writes anywhere), else /sys or /proc; skip when neither refuses."""
    candidates = []
    if os.geteuid() != 0:
        ro = tmp_path / "read_only"
        ro.mkdir()
        ro.chmod(0o555)
        candidates.append(ro)
    candidates += [Path("/sys"), Path("/proc")]
    for d in candidates:
        try:
            fd = os.open(d / ".pcmm_probe", os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
        except OSError:
            return d
        os.close(fd)
        os.unlink(d / ".pcmm_probe")
    pytest.skip("no folder here refuses writes")


def steps_from_samples(traj) -> int:
    """Accepted steps recorded: each segment holds its start plus one sample per step."""
    return sum(len(s.t) - 1 for s in traj.segments)


# ---- 1. an output the operating system refuses --------------------------------------------------
def test_unwritable_output_is_kept_in_a_fallback_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = unwritable_folder(tmp_path)
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.5)
    rc, out, err = cli(["run", scene, "--out", bad / "run.npz", "--summary", bad / "run.json",
                        "--csv", tmp_path / "run.csv", "--quiet"], capsys)
    assert rc == 4
    for name in ("run.npz", "run.json"):
        line = next(x for x in err.splitlines() if str(bad / name) in x)
        assert "cannot write it" in line and "errno" in line and "instead" in line
        kept = Path(re.search(r"written to (\S+) instead", line).group(1))
        assert kept.parent == tmp_path and kept.is_file()
    back = pcmm.Trajectory.load(tmp_path / "run.npz")
    rows = list(csv.reader((tmp_path / "run.csv").open()))
    assert len(rows) - 1 == back.t.size and back.status == "complete"  # the CSV (own folder) and the fallback agree
    assert json.loads((tmp_path / "run.json").read_text())["status"] == "complete"


def test_a_file_size_limit_is_an_error_naming_the_file_not_a_kill(tmp_path):
    """RLIMIT_FSIZE (a quota-like limit; writing past it raises SIGXFSZ, which kills by default):
    the small summary is written, the trajectory refused with the OS error, no temporary file left."""
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=2.0)  # trajectory about 58 kB, summary about 49 kB
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, (54000, 54000)); "
            "from pcmm.cli import main; sys.exit(main(sys.argv[1:]))")
    p = subprocess.run([PY, "-c", code, "run", str(scene), "--out", "t.npz", "--summary", "s.json", "--quiet"],
                       cwd=tmp_path, env=env(), capture_output=True, text=True, timeout=120)
    assert p.returncode == 4, p.stderr
    assert "Traceback" not in p.stderr and "t.npz: cannot write it: File too large" in p.stderr
    assert "this output is lost" in p.stderr  # said honestly: every folder is under the same limit
    assert json.loads((tmp_path / "s.json").read_text())["status"] == "complete"
    assert not list(tmp_path.glob(".*.tmp")) and not (tmp_path / "t.npz").exists()


# ---- 2. signals ---------------------------------------------------------------------------------
@pytest.mark.slow  # two subprocess runs, each signalled once it has recorded a segment
def test_sigterm_and_sighup_keep_the_partial_like_ctrl_c(tmp_path):
    """Two long bouncing-ball runs, stopped once they have recorded their first segment by SIGTERM
    (a batch scheduler, ``timeout``) and SIGHUP (a closed terminal): each writes its partial
    trajectory and summary, marked partial, exits 128 + the signal, and its summary's step count is
    its samples'.  (The signal came after 2.5 s of CPU, assuming the start-up cost less: 0.7 to
    0.9 s here, but a slower machine's start-up takes longer, and the run then kept no step.)"""
    scene = builders.endless_ball(tmp_path / "scene")
    procs = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        d = tmp_path / sig.name
        d.mkdir()
        procs[sig] = (d, processes.marked_cli(["run", scene, "--out", "p.npz", "--summary", "p.json", "--quiet"],
                                              d / "recorded", cwd=d, preexec_fn=suite_checks.default_signals))
    for sig, (d, proc) in procs.items():  # past start-up: the run has taken its first steps
        processes.wait_for_file(proc, d / "recorded", "its first segment was recorded")
        proc.send_signal(sig)
    for sig, (d, proc) in procs.items():
        out, err = proc.communicate(timeout=60)
        assert "Traceback" not in err
        assert proc.returncode == 128 + sig, err
        saved = pcmm.Trajectory.load(d / "p.npz")
        summary = json.loads((d / "p.json").read_text())
        assert saved.status == summary["status"] == "partial"
        assert sig.name in saved.message and sig.name in err
        assert summary["stats"]["steps"] == steps_from_samples(saved) > 0
        assert summary["stats"]["rhs_evals"] >= summary["stats"]["steps"]


def _ignoring_sighup() -> None:  # what ``nohup`` does before it starts the command
    suite_checks.default_signals()
    signal.signal(signal.SIGHUP, signal.SIG_IGN)


def test_a_run_started_under_nohup_outlives_the_terminal(tmp_path):
    """``nohup pcmm run ...``: SIGHUP was ignored by whoever started pcmm, so it stays ignored (the
    run goes on through a closed terminal and completes), while SIGTERM is still pcmm's to answer.
    (Before, pcmm installed its handler over the ignored SIGHUP and stopped with a partial run.)"""
    scene = builders.ball(tmp_path / "scene", 1.0, t_end=20.0)
    proc = subprocess.Popen([PY, "-m", "pcmm.cli", "run", str(scene), "--out", "p.npz", "--summary", "p.json",
                             "--quiet"], cwd=tmp_path, env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=_ignoring_sighup)
    from test_fuzz import _catches
    _catches(proc, signal.SIGTERM)  # pcmm handles signals from here on
    status = dict(ln.split(":", 1) for ln in Path(f"/proc/{proc.pid}/status").read_text().splitlines()) \
        if Path(f"/proc/{proc.pid}/status").exists() else None
    proc.send_signal(signal.SIGHUP)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert json.loads((tmp_path / "p.json").read_text())["status"] == "complete"
    if status is not None and proc.returncode == 0:  # it was still running when asked: SIGHUP ignored, SIGTERM caught
        assert int(status["SigIgn"], 16) >> (signal.SIGHUP - 1) & 1
        assert not int(status["SigCgt"], 16) >> (signal.SIGHUP - 1) & 1


def test_partial_stats_count_the_interrupted_segment(tmp_path):
    """An interrupt inside a segment: the steps it took are recorded and counted."""
    scene = pcmm.load_scene(builders.spring_pendulum(tmp_path / "s", 10.0, 0.1, t_end=50.0))  # one long segment

    def progress(t):
        if t > 2.0:
            raise KeyboardInterrupt
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(scene, progress=progress)
    partial = info.value.partial
    assert partial.stats["steps"] == steps_from_samples(partial)
    assert info.value.exit_code == 130


def test_a_signal_in_the_first_segment_before_any_sample_keeps_an_empty_partial(tmp_path, capsys, monkeypatch):
    """SIGTERM inside simulate's loop before the first segment is recorded (the first segment's
    compiled set-up, slow on a loaded machine: CI saw it 3.4 s into a run): the run keeps its
    partial result, empty and marked partial, with exit status 143, as a signal before simulate
    does; it used to raise the failure with nothing written (no --out, no --summary)."""
    loop = importlib.import_module("pcmm.run.loop")  # (imported here: run alone, no test before loaded it)

    def integrate_segment(run, progress):
        raise Terminated(signal.SIGTERM)  # what pcmm.signals.as_interrupts raises on SIGTERM
    monkeypatch.setattr(loop, "integrate_segment", integrate_segment)
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.2)
    rc, _, err = cli(["run", scene, "--out", tmp_path / "t.npz", "--summary", tmp_path / "s.json", "--quiet"], capsys)
    assert rc == 143, (rc, err)
    traj = pcmm.Trajectory.load(tmp_path / "t.npz")
    assert traj.status == "partial" and "SIGTERM" in traj.message and not traj.segments
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["status"] == "partial" and summary["message"] == traj.message
    assert "the partial trajectory is saved in" in err


def test_a_second_ctrl_c_while_the_partial_is_recorded_loses_nothing(tmp_path, monkeypatch):
    """Ctrl-C mid-segment, then a second Ctrl-C while that segment's samples are recorded: the
    second waits, and the partial ends where the first stopped the run."""
    sim = importlib.import_module("pcmm.run.recording")  # (imported here: run alone, no test before loaded it)
    scene = pcmm.load_scene(builders.spring_pendulum(tmp_path / "s", 10.0, 0.1, t_end=50.0))  # one long segment
    real = sim.record_samples
    state = {"interrupted": False, "sent": 0}

    def record(*args):
        if state["interrupted"] and not state["sent"]:
            state["sent"] += 1
            os.kill(os.getpid(), signal.SIGINT)  # arrives while the samples are being recorded
            time.sleep(0.05)
        return real(*args)

    def progress(t):
        if t > 1.5 and not state["interrupted"]:
            state["interrupted"] = t
            raise KeyboardInterrupt
    monkeypatch.setattr(sim, "record_samples", record)
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(scene, progress=progress)
    assert state["sent"] == 1
    partial = info.value.partial  # one segment: before the fix the second Ctrl-C dropped it, and all with it
    assert partial.segments and 1.4 < partial.t[-1] <= state["interrupted"]
    assert partial.stats["steps"] == steps_from_samples(partial)


# ---- 3. no silent replacement -----------------------------------------------------------------
def test_the_same_path_for_two_outputs_is_refused(tmp_path, capsys):
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.2)
    target = tmp_path / "x.npz"
    rc, _, err = cli(["run", scene, "--out", target, "--summary", tmp_path / "." / "x.npz", "--quiet"], capsys)
    assert rc == 2 and "is also the --out output" in err and not target.exists()
    rc, _, err = cli(["run", scene, "--csv", target, "--plots", target, "--quiet"], capsys)
    assert rc == 2 and "--plots" in err and not target.exists()


def _appearing_during_the_run(monkeypatch, path: Path, content: bytes, fail: bool = False):
    """Make ``path`` appear while the run computes (a concurrent run finishing first)."""
    sim = importlib.import_module("pcmm.run.loop")  # (imported here: run alone, no test before loaded it)
    real = sim.simulate

    def simulate(scene, options=sim.RunOptions(), progress=None):
        try:
            return real(scene, options, progress)
        finally:
            path.write_bytes(content)
    monkeypatch.setattr(sim, "simulate", simulate)


def test_a_file_created_during_the_run_is_never_replaced(tmp_path, capsys, monkeypatch):
    """The existence check at start-up passes; another run writes --out meanwhile.  The rename is
    create-if-absent: that file stays, and this run's result goes next to it, said."""
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.3)
    out = tmp_path / "run.npz"
    _appearing_during_the_run(monkeypatch, out, b"the other run's result")
    rc, _, err = cli(["run", scene, "--out", out, "--quiet"], capsys)
    assert rc == 4 and out.read_bytes() == b"the other run's result"
    assert f"written to {tmp_path / 'run-2.npz'} instead" in err
    assert pcmm.Trajectory.load(tmp_path / "run-2.npz").t[-1] == pytest.approx(0.3)


def test_a_failing_runs_partial_never_replaces_a_finished_result(tmp_path, capsys, monkeypatch):
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=5.0, merge=False)  # fails: accumulation without merge_to
    out = tmp_path / "run.npz"
    _appearing_during_the_run(monkeypatch, out, b"finished")
    rc, _, err = cli(["run", scene, "--out", out, "--summary", tmp_path / "s.json", "--quiet"], capsys)
    assert rc == 3 and out.read_bytes() == b"finished"
    partial = pcmm.Trajectory.load(tmp_path / "run-2.npz")
    assert partial.status == "partial" and str(tmp_path / "run-2.npz") in err
    assert json.loads((tmp_path / "s.json").read_text())["status"] == "partial"  # the summary, marked partial


def test_partials_get_names_of_their_own(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=5.0, merge=False)
    for _ in range(3):
        assert cli(["run", scene, "--quiet"], capsys)[0] == 3
    names = sorted(p.name for p in tmp_path.glob("scene-partial*.npz"))
    assert names == ["scene-partial-2.npz", "scene-partial-3.npz", "scene-partial.npz"]


def test_plot_refuses_to_overwrite_without_force_and_names_a_file_given_as_folder(tmp_path, capsys):
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.3)
    traj = tmp_path / "t.npz"
    assert cli(["run", scene, "--out", traj, "--quiet"], capsys)[0] == 0
    figs = tmp_path / "figs"
    rc, out, _ = cli(["plot", traj, "--out", figs], capsys)
    assert rc == 0
    first = {p.name: p.read_bytes() for p in figs.iterdir()}
    (figs / "energy.png").write_bytes(b"mine")
    rc, _, err = cli(["plot", traj, "--out", figs], capsys)
    assert rc == 2 and "already holds figures" in err and "energy.png" in err
    assert (figs / "energy.png").read_bytes() == b"mine"  # nothing moved: all names are checked first
    assert not list(figs.parent.glob(".figs.*"))  # the staging folder is gone
    assert cli(["plot", traj, "--out", figs, "--force"], capsys)[0] == 0
    assert (figs / "energy.png").read_bytes() == first["energy.png"]
    rc, _, err = cli(["plot", traj, "--out", traj], capsys)
    assert rc == 2 and "is a file" in err
    rc, _, err = cli(["run", scene, "--plots", figs, "--quiet"], capsys)  # run --plots: the same rule
    assert rc == 2 and "already holds figures" in err


# ---- 4. CSV -----------------------------------------------------------------------------------
def test_csv_quotes_names_and_neutralises_formulas(tmp_path):
    """A configuration named like a formula and a link whose name holds a comma, a quote and a
    newline: every row has as many cells as the header, the formula cell starts with an
    apostrophe, and the numbers read back equal the trajectory's."""
    import tomli_w
    link = 'ar,m "x"\nend'
    urdf = builders.robot_xml("p", builders.link_xml("frame"), builders.joint_xml("J1", "revolute", "frame", "QQQ"), builders.bar_xml("QQQ", 0.5, 1.0))
    urdf = urdf.replace("QQQ", 'ar,m &quot;x&quot;&#10;end')
    doc = builders.base_doc("p", "=HYPERLINK(1)", {"=HYPERLINK(1)": "p.urdf"}, {"J1": 0.3}, {"J1": 0.0}, t_end=0.1)
    (tmp_path / "p.urdf").write_text(urdf)
    (tmp_path / "s.toml").write_text(tomli_w.dumps(doc))
    traj = pcmm.simulate(pcmm.load_scene(tmp_path / "s.toml"))
    traj.to_csv(tmp_path / "t.csv")
    rows = list(csv.reader((tmp_path / "t.csv").open(newline="")))
    header, body = rows[0], rows[1:]
    assert all(len(r) == len(header) for r in body) and len(body) == traj.t.size
    assert {r[1] for r in body} == {"'=HYPERLINK(1)"}
    col = header.index(f"theta_{link} [rad]")
    assert np.array_equal([float(r[col]) for r in body], traj.series("theta", link))


# ---- 5. models Pinocchio rejects ----------------------------------------------------------------
def _pinocchio_rejects(tmp_path, transition: bool):
    """config2's URDF passes pcmm's reader but not Pinocchio's (a <limit> without attributes)."""
    good = builders.robot_xml("p", builders.link_xml("frame"), builders.joint_xml("J1", "revolute", "frame", "bar"), builders.bar_xml("bar", 0.5, 1.0))
    bad = re.sub(r"<limit [^>]*/>", "<limit/>", good)
    trs = []
    if transition:
        trs = [{"name": "latch", "type": "latch", "from": "c1", "to": "c2", "cut": [],
                "guard": {"type": "coordinate", "measure": {"joint": "J1"}, "value": -0.5, "direction": "decreasing"},
                "contact": {"a": "frame", "point_a": [0.5 * math.cos(-0.5), 0.5 * math.sin(-0.5)], "b": "bar",
                            "point_b": [0.5, 0.0], "normal": [-math.sin(-0.5), math.cos(-0.5)]}}]
    doc = builders.base_doc("p", "c1", {"c1": "good.urdf", "c2": "bad.urdf"}, {"J1": 0.0}, {"J1": 0.0}, t_end=1.0,
                      transitions=trs)
    return builders.write_scene(tmp_path, doc, {"good.urdf": good, "bad.urdf": bad})


def test_check_builds_every_configurations_model(tmp_path, capsys):
    scene = _pinocchio_rejects(tmp_path, transition=False)
    rc, _, err = cli(["check", scene], capsys)
    assert rc == 2 and "configuration 'c2'" in err and "bad.urdf" in err and "Pinocchio" in err


def test_a_model_error_mid_run_keeps_the_partial(tmp_path):
    scene = pcmm.load_scene(_pinocchio_rejects(tmp_path, transition=True))
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(scene)
    partial = info.value.partial
    assert partial.status == "partial" and "bad.urdf" in str(info.value)
    # the pendulum from rest reaches J1 = -0.5 rad; the samples end there
    assert partial.segments[-1].q[-1, 0] == pytest.approx(-0.5, abs=1e-9)


# ---- 6. tracebacks on hostile input -------------------------------------------------------------
HOSTILE = ["$\\foo$", 'a&b"c\\d', "x$y", "=cmd|' /C calc'!A0\té ∑"]  # more, drawn at random: test_fuzz.py


def hostile_names(name: str, xml_name: str | None = None, lead: bool = False) -> dict[str, str]:
    """The names a hostile scene gives its elements: ``name`` with a one-letter prefix (C for
    the configuration, T transition, L link, J joint, F force, R the merged configuration), or
    with ``lead`` leading every name (``name`` itself, ``name + "_r"``, ...)."""
    x = name if xml_name is None else xml_name
    kinds = {"C": name, "R": name, "T": name, "F": name, "L": x, "J": x}
    suffix = {"R": "_r", "J": "_j"}
    return {k: (v + suffix.get(k, "") if lead else k + v) for k, v in kinds.items()}


def hostile_scene(folder: Path, name: str, xml_name: str | None = None, lead: bool = False) -> Path:
    """A pendulum falling onto a stop that merges it, every element named by :func:`hostile_names`
    (links and joints by ``xml_name``, default ``name``: XML cannot hold control characters)."""
    from xml.sax.saxutils import escape

    import tomli_w
    n = hostile_names(name, xml_name, lead)
    qs = -0.5  # the stop's angle, where the merged configuration fixes the bar
    urdf = builders.robot_xml("p", builders.link_xml("frame"), builders.joint_xml("JJJ", "revolute", "frame", "LLL"), builders.bar_xml("LLL", 0.5, 1.0))
    rest = builders.robot_xml("r", builders.link_xml("frame"), builders.joint_xml("JJJ", "fixed", "frame", "LLL", yaw=qs), builders.bar_xml("LLL", 0.5, 1.0))

    def quoted(text):
        return text.replace("JJJ", escape(n["J"], {'"': "&quot;", "\t": "&#9;", "\n": "&#10;"})) \
                   .replace("LLL", escape(n["L"], {'"': "&quot;", "\t": "&#9;", "\n": "&#10;"}))
    tr = builders.stop(n["T"], n["C"], 0.5, {"type": "coordinate", "measure": {"joint": n["J"]}, "value": qs,
                                       "direction": "decreasing"},
                 {"a": "frame", "point_a": [0.5 * math.cos(qs), 0.5 * math.sin(qs)], "b": n["L"],
                  "point_b": [0.5, 0.0], "normal": [-math.sin(qs), math.cos(qs)]}, merge_to=n["R"])
    doc = builders.base_doc(name, n["C"], {n["C"]: "p.urdf", n["R"]: "r.urdf"}, {n["J"]: 0.0}, {n["J"]: 0.0},
                      t_end=0.6, transitions=[tr],
                      forces=[{"name": n["F"], "type": "damper", "on": {"joint": n["J"]},
                               "measure": {"joint": n["J"]}, "c": 0.01, "configurations": [n["C"]]}])
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "p.urdf").write_text(quoted(urdf), encoding="utf-8")
    (folder / "r.urdf").write_text(quoted(rest), encoding="utf-8")
    path = folder / "scene.toml"
    path.write_text(tomli_w.dumps(doc), encoding="utf-8")
    return path


@pytest.mark.parametrize("name", HOSTILE)
def test_hostile_names_in_every_output(tmp_path, capsys, name):
    """Every output of a run whose names hold mathtext, quotes, backslashes, ampersands, tabs,
    formula prefixes and non-ASCII: no traceback, and each output reads back with the names."""
    scene = hostile_scene(tmp_path / "s", name)
    loaded = pcmm.load_scene(scene)
    assert f"L{name}" in loaded.configurations[f"C{name}"].info.links
    o = tmp_path / "o"
    o.mkdir()
    # the figures' comparison run draws one figure of its own (angle_differences, its titles the
    # link names): drawn for the mathtext name; the other names check this run's figures alone
    alone = [] if name == HOSTILE[0] else ["--no-comparison"]
    rc, out, err = cli(["run", scene, "--out", o / "t.npz", "--summary", o / "s.json", "--csv", o / "t.csv",
                        "--html", o / "t.html", "--plots", o / "figs", *alone], capsys)
    assert rc == 0, err
    traj = pcmm.Trajectory.load(o / "t.npz")
    assert traj.events and traj.events[0]["name"] == f"T{name}"
    assert json.loads((o / "s.json").read_text())["events"][0]["name"] == f"T{name}"
    header = next(csv.reader((o / "t.csv").open(newline="")))
    assert f"theta_L{name} [rad]" in header
    assert len(list((o / "figs").glob("*.png"))) >= 3 and (o / "t.html").stat().st_size > 1000
    assert (o / "figs" / "angle_differences.png").exists() == (not alone)


def _damaged(tmp_path: Path) -> dict[str, Path]:
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.2)
    good = tmp_path / "good.npz"
    pcmm.simulate(pcmm.load_scene(scene)).save(good)
    data = good.read_bytes()
    files = {"empty": b"", "truncated": data[: len(data) // 2], "text": b"hello", "zip-of-junk": None,
             "foreign": None, "wrong-shapes": None, "folder": None}
    out = {}
    for k, v in files.items():
        p = tmp_path / f"{k}.npz"
        if v is not None:
            p.write_bytes(v)
        out[k] = p
    np.savez(out["foreign"], a=np.arange(3))
    import zipfile
    with zipfile.ZipFile(out["zip-of-junk"], "w") as z:
        z.writestr("header.npy", b"\x93NUMPY junk")
    with np.load(good) as z:
        arrays = dict(z)
    arrays["s0_q"] = arrays["s0_q"][:, :0]
    np.savez(out["wrong-shapes"], **arrays)
    out["folder"].mkdir()
    return out


def test_damaged_trajectory_files_are_named_not_tracebacks(tmp_path, capsys):
    for kind, path in _damaged(tmp_path).items():
        for args in (["plot", path, "--out", tmp_path / f"f_{kind}"], ["replay", path, "--html", tmp_path / f"{kind}.html"]):
            rc, _, err = cli(args, capsys)
            assert rc == 2 and err.count("pcmm: error:") == 1 and str(path) in err, (kind, err)


def test_a_joint_that_changes_type_between_configurations_is_named_at_load(tmp_path):
    planar = builders.robot_xml("a", builders.link_xml("frame"), builders.joint_xml("J", "planar", "frame", "b"), builders.solid_xml("b", 1.0, 0.1))
    revolute = builders.robot_xml("b", builders.link_xml("frame"), builders.joint_xml("J", "revolute", "frame", "b"), builders.solid_xml("b", 1.0, 0.1))
    doc = builders.base_doc("x", "c1", {"c1": "a.urdf", "c2": "b.urdf"}, {"J": [0.0, 0.0, 0.0]}, {"J": [0.0, 0.0, 0.0]})
    with pytest.raises(pcmm.SceneError, match=r"joint 'J' is revolute in 'c2' \(b.urdf\) but planar in 'c1'"):
        pcmm.load_scene(builders.write_scene(tmp_path, doc, {"a.urdf": planar, "b.urdf": revolute}))


@pytest.mark.parametrize("kind", ["huge-int", "deep", "nul", "symlink-loop", "bom"])
def test_scene_validator_on_hostile_structure(tmp_path, kind):
    scene = builders.ball(tmp_path / "s", 0.5, t_end=0.2)
    text = scene.read_text()
    if kind == "huge-int":
        assert "t_end = 0.2" in text
        text = text.replace("t_end = 0.2", "t_end = 1" + "0" * 400)
    elif kind == "deep":
        text += "\n[junk]\nx = " + "[" * 5000 + "]" * 5000 + "\n"
    elif kind == "nul":
        text = text.replace('"free.urdf"', '"fr\\u0000ee.urdf"')
    elif kind == "symlink-loop":
        os.symlink(tmp_path / "s" / "l2.urdf", tmp_path / "s" / "l1.urdf")
        os.symlink(tmp_path / "s" / "l1.urdf", tmp_path / "s" / "l2.urdf")
        text = text.replace('"free.urdf"', '"l1.urdf"')
    elif kind == "bom":
        scene.write_text("\ufeff" + text, encoding="utf-8")
        assert pcmm.load_scene(scene).t_end == 0.2  # accepted: the mark is not part of the TOML
        return
    scene.write_text(text)
    with pytest.raises(pcmm.SceneError) as info:
        pcmm.load_scene(scene)
    msg = str(info.value)
    assert str(scene) in msg
    expected = {"huge-int": "scene.t_end: = an integer of 401 digits", "deep": "nested too deeply",
                "nul": "configurations.free.urdf", "symlink-loop": "configurations.free.urdf"}[kind]
    assert expected in msg


def test_ctrl_c_during_start_up_is_a_message(tmp_path):
    """Ctrl-C while the ``pcmm`` command loads Pinocchio and scipy (the script pip writes for
    the console entry point, reproduced here): a message and status 130, no traceback."""
    script = tmp_path / "pcmm"
    # pip's script.  A Ctrl-C during Python's own start-up, before any pcmm code runs, is Python's
    # traceback to print: each delay counts from the moment pcmm handles signals, the first thing
    # pcmm.cli does (SIGTERM in the process's caught mask; on a loaded machine a fixed delay from
    # the process's start, or from a mark before `from pcmm.cli import main`, landed before it)
    script.write_text("import sys\nfrom pcmm.cli import main\nsys.exit(main())\n")
    scene = builders.ball(tmp_path / "s", 0.5, t_end=0.2)
    for delay in (0.0, 0.05, 0.3, 0.6, 1.0):
        proc = subprocess.Popen([PY, str(script), "check", str(scene)], env=env(), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, preexec_fn=suite_checks.default_signals)
        from test_fuzz import _catches
        _catches(proc, signal.SIGTERM)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert "Traceback" not in err, (delay, err)
        # -SIGINT only when the signal came after the work was done, while the interpreter shut
        # down (Python restores the default handler then): the check's result is printed
        assert proc.returncode in (0, 130) or (proc.returncode == -signal.SIGINT and "valid" in out), \
            (delay, proc.returncode, err)
        if proc.returncode == 130:
            assert "pcmm: interrupted by the user (Ctrl-C)" in err


# ---- 7. hangs ----------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["DOP853", "RK45", "DOP853F", "RK4", "Radau", "LSODA"])
def test_an_absurd_initial_velocity_ends_at_once(tmp_path, method):
    scene = pcmm.load_scene(builders.ball(tmp_path, 0.5, v0=-1e160, t_end=1.0, solver={"method": method}))
    with suite_checks.deadline(10.0, f"v0 = 1e160 with {method}"):
        with pytest.raises(pcmm.SimulationError, match=r"initial\.v: .* faster than light"):
            pcmm.simulate(scene)


def test_a_non_finite_derivative_stops_the_run(tmp_path):
    """A spring so stiff that the first derivative overflows (k = 1e308 at 0.1 rad -> 1e307 / I)."""
    scene = pcmm.load_scene(builders.spring_pendulum(tmp_path, 1e308, 1e-3))
    with suite_checks.deadline(10.0, "overflowing derivative"):
        with pytest.raises(pcmm.SimulationError, match="derivative of the state is not finite"):
            pcmm.simulate(scene)


def test_replay_fps_and_frames_are_capped(tmp_path, capsys):
    scene = builders.ball(tmp_path / "s", 0.5, t_end=0.2)
    t = tmp_path / "t.npz"
    assert cli(["run", scene, "--out", t, "--quiet"], capsys)[0] == 0
    with pytest.raises(SystemExit):
        cli_main(["replay", str(t), "--fps", "1e6"])
    assert "at most 1000 frames per second" in capsys.readouterr().err
    traj = pcmm.Trajectory.load(t)
    traj.segments[-1].t[-1] = 1e4  # a long run: 1e4 s at 60 fps
    long = tmp_path / "long.npz"
    traj.save(long)
    rc, _, err = cli(["replay", long, "--html", tmp_path / "x.html"], capsys)
    assert rc == 2 and "give --fps 20 or less" in err


# ---- 8. silent wrong answers -------------------------------------------------------------------
@pytest.mark.parametrize("tag,message", [
    ('<dynamics damping="0.5"/>', "<dynamics damping='0.5'> is not modelled"),
    ('<dynamics friction="0.1"/>', "<dynamics friction='0.1'> is not modelled"),
    ('<mimic joint="J0" multiplier="2"/>', "<mimic joint='J0'> is not modelled"),
])
def test_urdf_dynamics_and_mimic_are_refused(tmp_path, tag, message):
    urdf = builders.robot_xml("p", builders.link_xml("frame"), builders.joint_xml("J1", "revolute", "frame", "bar").replace("</joint>", tag + "</joint>"),
                    builders.bar_xml("bar", 0.5, 1.0))
    doc = builders.base_doc("p", "c1", {"c1": "p.urdf"}, {"J1": 0.0}, {"J1": 0.0})
    with pytest.raises(pcmm.SceneError, match=re.escape(message)):
        pcmm.load_scene(builders.write_scene(tmp_path, doc, {"p.urdf": urdf}))
    zero = urdf.replace(tag, '<dynamics damping="0" friction="0.0"/>')  # zero damping is what pcmm models
    pcmm.load_scene(builders.write_scene(tmp_path / "z", doc, {"p.urdf": zero}))


def test_an_initial_angle_beyond_precision_is_refused(tmp_path):
    path = builders.pendulum(tmp_path, 0.5, q0=1e17)
    with pytest.raises(pcmm.SceneError, match=r"initial.q.J1: = 1e\+17: an angle beyond \+-1e\+06 rad .* 16 rad apart"):
        pcmm.load_scene(path)


def test_an_impact_that_creates_energy_is_refused(tmp_path):
    """Example 1 with link 1's inertia 1e300: the plastic latch's energy balance breaks down."""
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    shutil.copytree(ROOT / "urdf", tmp_path / "urdf")
    for f in ("three_bar_config1.urdf", "three_bar_config2.urdf"):
        p = tmp_path / "urdf" / f
        text = p.read_text()
        link1 = text.index('<link name="link1"')
        m = re.compile(r'<inertia [^>]*/>').search(text, link1)
        p.write_text(text[:m.start()] + '<inertia ixx="1e300" ixy="0" ixz="0" iyy="1e300" iyz="0" izz="1e300"/>'
                     + text[m.end():])
    scene = pcmm.load_scene(tmp_path / "examples" / "three_bar.toml")
    with pytest.raises(pcmm.SimulationError, match="would create energy|not finite") as info:
        pcmm.simulate(scene)
    assert info.value.partial is not None


def test_a_body_starting_inside_a_stop_is_an_error_naming_the_transition(tmp_path):
    scene = pcmm.load_scene(builders.ball(tmp_path, 0.5, h=-0.01, v0=-1.0, t_end=0.5))
    with pytest.raises(pcmm.SimulationError, match=r"transition 'floor': the run starts on the far side"):
        pcmm.simulate(scene)
    pcmm.simulate(pcmm.load_scene(builders.ball(tmp_path / "ok", 0.5, h=0.0, v0=1.0, t_end=0.1)))  # touching, leaving: fine


def test_a_latch_with_a_reversed_normal_is_an_error_naming_the_normal(tmp_path):
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    shutil.copytree(ROOT / "urdf", tmp_path / "urdf")
    path = tmp_path / "examples" / "three_bar.toml"
    path.write_text(path.read_text().replace("normal = [0.0, 1.0]", "normal = [0.0, -1.0]"))
    with pytest.raises(pcmm.SimulationError, match=r"tensile .* normal \(0, -1\)"):
        pcmm.simulate(pcmm.load_scene(path))


def test_non_finite_numbers_never_reach_the_summary(tmp_path, capsys, monkeypatch):
    sim = importlib.import_module("pcmm.run.loop")  # (imported here: run alone, no test before loaded it)
    real = sim.simulate

    def overflowing(scene, options=sim.RunOptions(), progress=None):
        traj = real(scene, options, progress)
        traj.events[0]["impulse"]["normal"] = float("inf")
        return traj
    monkeypatch.setattr(sim, "simulate", overflowing)
    scene = builders.ball(tmp_path / "s", 0.5, t_end=0.6)
    rc, _, err = cli(["run", scene, "--summary", tmp_path / "s.json", "--out", tmp_path / "t.npz", "--quiet"], capsys)
    assert rc == 3 and "events[0].impulse.normal = inf" in err
    assert not (tmp_path / "s.json").exists() and (tmp_path / "t.npz").is_file()  # the other output is kept


# ---- 9. diagnoses -----------------------------------------------------------------------------
def test_max_steps_on_a_smooth_run_says_raise_max_steps(tmp_path):
    """A free pendulum at max_step 1e-3 s for 1 s needs 1000 steps; with max_steps = 300 the
    message estimates the budget (1000 +- rounding) and does not call the problem stiff."""
    scene = pcmm.load_scene(builders.pendulum(tmp_path, 0.5, qs=-3.0, q0=0.0, t_end=1.0))
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(scene, pcmm.RunOptions(max_steps=300, max_step=1e-3))
    msg = str(info.value)
    need = int(re.search(r"needs about (\d+) steps", msg).group(1))
    assert 995 <= need <= 1005 and "raise solver.max_steps" in msg and "too stiff" not in msg


# ---- 10. terminal hygiene ---------------------------------------------------------------------
def test_control_characters_in_names_are_printed_escaped(tmp_path, capsys):
    scene = hostile_scene(tmp_path / "s", "\x1b[31mred\x07", xml_name="plain")
    rc, out, err = cli(["run", scene], capsys)
    assert rc == 0
    assert "\x1b" not in out + err and "\x07" not in out + err
    assert "\\x1b[31mred\\x07" in out


def _pendulum_on_a_stop(folder: Path, method: str, step: float, normal_sign: float = 1.0, k: float = 2000.0):
    """A bar on J1 with a torsion spring (k), launched from 0 at -50 rad/s onto a stop at -0.3 rad
    (amplitude 50 / 105 = 0.48 rad > 0.3)."""
    qs, L = -0.3, 0.6
    urdf = builders.robot_xml("pend", builders.link_xml("frame"), builders.joint_xml("J1", "revolute", "frame", "link1"), builders.bar_xml("link1", L, 1.5))
    tr = builders.stop("stop", "c1", 0.5, {"type": "coordinate", "measure": {"joint": "J1"}, "value": qs,
                                     "direction": "decreasing"},
                 {"a": "frame", "point_a": [L * math.cos(qs), L * math.sin(qs)], "b": "link1", "point_b": [L, 0.0],
                  "normal": [-normal_sign * math.sin(qs), normal_sign * math.cos(qs)]})
    doc = builders.base_doc("p", "c1", {"c1": "p.urdf"}, {"J1": 0.0}, {"J1": -50.0}, t_end=0.5,
                      solver={"method": method, "step": step}, transitions=[tr],
                      forces=[{"name": "spring", "type": "spring", "on": {"joint": "J1"}, "measure": {"joint": "J1"},
                               "k": k}])
    return pcmm.load_scene(builders.write_scene(folder, doc, {"p.urdf": urdf}))


def test_an_rk4_blow_up_names_the_step_and_a_wrong_normal_the_normal(tmp_path):
    """sqrt(k / I) = sqrt(2000 / 0.18) = 105 rad/s: RK4's stability limit is h < 2.8 / 105 = 0.027 s.
    At h = 0.1 s the state would oscillate wildly and cross the guard backwards: the step is named
    before the run starts, with the largest stable step (2 sqrt 2 / omega on the imaginary axis,
    omega^2 = k / I).  With a sound step and the normal reversed, the normal is named."""
    with np.errstate(all="ignore"), pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(_pendulum_on_a_stop(tmp_path / "a", "RK4", 0.1))
    omega = math.sqrt(2000.0 / 0.18)  # at q = 0 the bar is horizontal: gravity adds no stiffness there
    limit = 2 * math.sqrt(2) / omega
    assert "RK4 is unstable at solver.step = 0.1 s" in str(info.value) and f"stable up to {limit:.3g} s" in str(info.value)
    traj = pcmm.simulate(_pendulum_on_a_stop(tmp_path / "b", "RK4", 0.002))  # below the limit: it bounces
    assert traj.events and traj.events[0]["normal_velocity"]["before"] < 0
    with pytest.raises(pcmm.SimulationError, match="the normal must point from link a towards link b"):
        pcmm.simulate(_pendulum_on_a_stop(tmp_path / "c", "DOP853", 1e-3, normal_sign=-1.0))


def test_a_closed_stdout_pipe_is_no_traceback_and_loses_no_file(tmp_path):
    """``pcmm run ... | head -0``: the reader is gone before anything is printed.  The outputs are
    written first, the printing is silenced, the status is 0."""
    scene = builders.ball(tmp_path / "s", 0.5, t_end=0.5)
    p = subprocess.Popen([PY, "-m", "pcmm.cli", "run", str(scene), "--out", "t.npz", "--summary", "s.json"],
                         cwd=tmp_path, env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # like `| head` exiting at once
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 0 and "Traceback" not in err and "BrokenPipe" not in err, err
    assert pcmm.Trajectory.load(tmp_path / "t.npz").t[-1] == pytest.approx(0.5)
    assert json.loads((tmp_path / "s.json").read_text())["status"] == "complete"


def test_sigterm_shuts_the_replay_server_down(tmp_path, capsys):
    """``pcmm replay`` serving, then SIGTERM: the meshcat server it started is gone. The scene's
    name carries an escape sequence: the replay's status line prints it escaped."""
    psutil = pytest.importorskip("psutil")
    scene = builders.ball(tmp_path / "s", 0.5, t_end=0.3)
    text = scene.read_text()
    assert text.count('name = "') >= 1
    scene.write_text(text.replace('name = "', 'name = "\\u001b[31m', 1))
    assert cli(["run", scene, "--out", tmp_path / "t.npz", "--quiet"], capsys)[0] == 0
    p = subprocess.Popen([PY, "-m", "pcmm.cli", "replay", str(tmp_path / "t.npz"), "--fps", "10"], cwd=tmp_path,
                         env={**env(), "PCMM_REPLAY_NO_WAIT": ""}, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    deadline = time.monotonic() + 120
    line, printed = "", ""
    while "press Ctrl-C" not in line and time.monotonic() < deadline:
        line = p.stdout.readline()
        printed += line
        if not line and p.poll() is not None:
            pytest.fail(f"replay ended early: {p.stderr.read()}")
    servers = [c for c in psutil.Process(p.pid).children(recursive=True)
               if "meshcat.servers.zmqserver" in " ".join(c.cmdline())]
    assert servers, "no meshcat server found"
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert "Traceback" not in err
    assert "\x1b" not in printed + err and "\\x1b[31m" in printed, printed
    for s in servers:
        assert not s.is_running() or s.status() == psutil.STATUS_ZOMBIE, f"meshcat server {s.pid} left running"


def _parallelograms(folder: Path, n: int, a=0.1, b=0.3, theta0=1.0, omega=2.0) -> Path:
    """n independent parallelogram four-bars (builders.parallelogram's, 0.5 m apart): n loops, 2n rows."""
    parts, cuts, q, v = [builders.link_xml("frame")], [], {}, {}
    for i in range(n):
        y = 0.5 * i
        parts += [builders.joint_xml(f"A{i}", "revolute", "frame", f"crank{i}", xyz=(0.0, y)), builders.bar_xml(f"crank{i}", a, 1.0),
                  builders.joint_xml(f"B{i}", "revolute", f"crank{i}", f"coupler{i}", xyz=(a, 0.0)),
                  builders.bar_xml(f"coupler{i}", b, 1.0),
                  builders.joint_xml(f"D{i}", "revolute", "frame", f"rocker{i}", xyz=(b, y)), builders.bar_xml(f"rocker{i}", a, 1.0)]
        cuts.append({"name": f"C{i}", "type": "revolute", "a": f"coupler{i}", "point_a": [b, 0.0],
                     "b": f"rocker{i}", "point_b": [a, 0.0]})
        q.update({f"A{i}": theta0, f"B{i}": -theta0, f"D{i}": theta0})
        v.update({f"A{i}": omega, f"B{i}": -omega, f"D{i}": omega})
    doc = builders.base_doc("loops", "c", {"c": {"urdf": "l.urdf", "cut_joints": cuts}}, q, v, g=0.0, t_end=0.2)
    doc["initial"]["independent"] = [f"A{i}" for i in range(n)]
    return builders.write_scene(folder, doc, {"l.urdf": builders.robot_xml("l", *parts)})


@pytest.mark.parametrize("n", [3, 5])
def test_many_well_conditioned_loops_start(tmp_path, n):
    """Before the fix the loops' conditioning measure fell as m^(-m/2) with the m = 2n rows, and
    three or more loops raised an internal Repartition at t = 0.  Each parallelogram keeps its
    crank speed (no gravity, the kinetic energy of each is constant): omega = 2 rad/s at the end."""
    traj = pcmm.simulate(pcmm.load_scene(_parallelograms(tmp_path, n)))
    assert traj.t[-1] == pytest.approx(0.2)
    for i in range(n):
        assert traj.series("omega", f"crank{i}")[-1] == pytest.approx(2.0, rel=1e-8)


def test_an_interrupt_in_flight_after_a_bounce_keeps_the_flight(tmp_path):
    """A ball dropped from 1 m bounces at t = sqrt(2 / g) = 0.4515 s (e = 0.9) and flies until
    0.4515 + 2 e sqrt(2 g) / g = 1.264 s; Ctrl-C at 0.6 s, inside that flight (whose state carries
    the work integral of the flight's energy audit): the partial holds the flight up to 0.6 s, or
    to the next progress report: a flight in the compiled segment loop reports every
    _PROGRESS_STEPS accepted steps (of at most max_step each)."""
    from pcmm.ode.integrators import _PROGRESS_STEPS
    scene = pcmm.load_scene(builders.ball(tmp_path, 0.9, t_end=3.0))

    def progress(t):
        if t > 0.6:
            raise KeyboardInterrupt
    with pytest.raises(pcmm.SimulationError) as info:
        pcmm.simulate(scene, pcmm.RunOptions(max_step=1e-3), progress=progress)
    partial = info.value.partial
    assert len(partial.events) == 1 and partial.events[0]["t"] == pytest.approx(math.sqrt(2 / builders.G), abs=1e-9)
    assert 0.55 < partial.t[-1] <= 0.6 + _PROGRESS_STEPS * 1e-3 and partial.stats["steps"] == steps_from_samples(partial)
    y = partial.series("q", "Y")[-1]
    t = partial.t[-1] - math.sqrt(2 / builders.G)
    assert y == pytest.approx(0.9 * math.sqrt(2 * builders.G) * t - builders.G * t * t / 2, abs=1e-9)  # the flight's parabola


def test_simulate_takes_a_path_and_names_a_wrong_argument(tmp_path):
    """pcmm.simulate("scene.toml") is what a newcomer types first: it runs the scene (the same
    run as from load_scene); anything else is a message naming what it takes, not an AttributeError."""
    path = builders.copy_example(tmp_path)
    by_path = pcmm.simulate(str(path), pcmm.RunOptions(t_end=0.2))
    by_scene = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=0.2))
    assert [e["t"] for e in by_path.events] == [e["t"] for e in by_scene.events] and len(by_path.events) == 1
    assert pcmm.simulate(path, pcmm.RunOptions(t_end=0.01)).events == []  # a Path too
    with pytest.raises(pcmm.UsageError, match="takes a Scene .* or a scene file's path, not dict"):
        pcmm.simulate({"t_end": 1.0})
    with pytest.raises(pcmm.UsageError, match=r"options are a pcmm.RunOptions\(...\), not dict"):
        pcmm.simulate(path, {"t_end": 1.0})
    with pytest.raises(pcmm.SceneError, match="missing.toml: scene file not found"):
        pcmm.simulate(tmp_path / "missing.toml")


def test_series_names_what_it_does_not_have():
    """traj.series("theta", "crank9") used to give an array of NaN, and a misspelt quantity a bare
    AttributeError: both are messages listing what the run has."""
    traj = pcmm.simulate(builders.EXAMPLES / "three_bar.toml", pcmm.RunOptions(t_end=0.2))
    with pytest.raises(pcmm.UsageError, match=r"no link 'crank9' in this run; the run's links: frame, link1, link2, link3"):
        traj.series("theta", "crank9")
    with pytest.raises(pcmm.UsageError, match="no quantity 'thetas'; the quantities are theta, omega"):
        traj.series("thetas", "link1")
    with pytest.raises(pcmm.UsageError, match="'q' needs a coordinate; the run's coordinates: O1, O2, O3"):
        traj.series("q")
    with pytest.raises(pcmm.UsageError, match="'kinetic' is the whole mechanism's"):
        traj.series("kinetic", "link1")
    q3 = traj.series("q", "O3")  # a coordinate the run has, absent after the latch: NaN there
    assert np.isnan(q3[-1]) and not np.isnan(q3[0])
