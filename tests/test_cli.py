"""``pcmm run``: output files, their round trip, overwrite protection, --no-impact, bad values."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

import pcmm
import pcmm.cli
from builders import EXAMPLES
from pcmm.results.trajectory import dumps_json

SCENE = EXAMPLES / "three_bar.toml"
LINKS = ["frame", "link1", "link2", "link3"]
ARRAYS = ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


def cli(argv):
    """pcmm.cli.main, with argparse's SystemExit turned into the exit status."""
    try:
        return pcmm.cli.main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 1


@pytest.fixture(scope="module")
def run_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    S, T, C = d / "summary.json", d / "traj.npz", d / "traj.csv"
    rc = cli(["run", SCENE, "--summary", S, "--out", T, "--csv", C, "--quiet"])
    assert rc == 0
    return S, T, C


@pytest.fixture(scope="module")
def in_memory():
    return pcmm.simulate(pcmm.load_scene(SCENE))


EVENT_KEYS = {"t", "kind", "transition", "from", "to", "restitution", "merge", "impulse", "normal_velocity",
              "omega_before", "omega_after", "v_before", "v_after", "joint_impulses",
              "kinetic_energy_before", "kinetic_energy_after"}


def test_summary_json_layout(run_files, in_memory):
    S, _, _ = run_files
    d = json.loads(S.read_text())
    assert {"scene", "configuration_initial", "configuration_final", "events", "final", "stats"} <= set(d)
    assert d["scene"].endswith("three_bar.toml")
    assert (d["configuration_initial"], d["configuration_final"]) == ("config1", "config2")
    assert len(d["events"]) == 1
    ev = d["events"][0]
    assert EVENT_KEYS <= set(ev), EVENT_KEYS - set(ev)
    assert (ev["kind"], ev["transition"], ev["from"], ev["to"], ev["restitution"], ev["merge"]) == \
        ("mobile", "latch", "config1", "config2", 0.0, True)
    assert set(ev["impulse"]) >= {"normal", "vector"} and len(ev["impulse"]["vector"]) == 2
    # the vector is the normal impulse along the event's unit normal
    np.testing.assert_allclose(ev["impulse"]["vector"], ev["impulse"]["normal"] * np.array(ev["normal"]), rtol=1e-14)
    assert set(ev["normal_velocity"]) == {"before", "after"}
    assert set(ev["omega_before"]) == set(LINKS) and set(ev["omega_after"]) == set(LINKS)
    assert set(ev["v_before"]) == {"O1", "O2", "O3"}
    assert set(ev["joint_impulses"]) == {"O1", "O2", "O3"}
    assert all(len(x) == 3 for x in ev["joint_impulses"].values())  # [fx, fy, mz]
    assert ev["kinetic_energy_after"] < ev["kinetic_energy_before"]
    assert {"t", "theta", "omega"} <= set(d["final"])
    assert d["final"]["t"] == 1.0
    assert set(d["final"]["theta"]) == set(LINKS)
    seg = in_memory.segments[-1]
    for link in LINKS:
        assert d["final"]["theta"][link] == seg.theta[-1, seg.links.index(link)]
        assert d["final"]["omega"][link] == seg.omega[-1, seg.links.index(link)]
    assert {"steps", "rhs_evals", "wall_s"} <= set(d["stats"])
    assert d["stats"]["steps"] == in_memory.stats["steps"] > 0
    assert d["stats"]["rhs_evals"] == in_memory.stats["rhs_evals"] > 0
    assert d["stats"]["wall_s"] > 0
    # events agree with the in-memory run through the JSON round trip
    assert d["events"] == json.loads(dumps_json(in_memory.events))


def test_npz_round_trip_equals_in_memory_run(run_files, in_memory):
    _, T, _ = run_files
    back = pcmm.Trajectory.load(T)
    assert (back.scene_name, back.impact, back.status) == ("three_bar", True, "complete")
    assert len(back.segments) == len(in_memory.segments) == 2
    for a, b in zip(back.segments, in_memory.segments):
        assert (a.configuration, a.coordinates, a.links, a.force_names, a.constraint_labels) == \
            (b.configuration, b.coordinates, b.links, b.force_names, b.constraint_labels)
        for name in ARRAYS:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert back.events == json.loads(dumps_json(in_memory.events))
    np.testing.assert_array_equal(back.t, in_memory.t)


def test_constraint_columns_carry_their_own_unit(tmp_path):
    """Example 2: the cut joint C's components in N, the crank's drive moment in N m (A is
    revolute); a stop-merge's hold, a normal force or a joint stop's moment, says both."""
    traj = pcmm.simulate(EXAMPLES / "double_folded.toml", pcmm.RunOptions(t_end=3.3))
    header = traj.to_csv(tmp_path / "r.csv").read_text().splitlines()[0].split(",")
    assert [h for h in header if h.startswith("constraint_")] == [
        "constraint_C.fx [N]", "constraint_C.fy [N]", "constraint_A.drive [N m]", "constraint_slider stop E.hold [N|N m]"]
    from pcmm.results.trajectory import constraint_unit
    assert constraint_unit("E.drive", {"E": "prismatic"}) == "N" and constraint_unit("O3.hold", {"O3": "revolute"}) == "N m"
    assert constraint_unit("P.mz", {}) == "N m" and constraint_unit("P.fn", {}) == "N"


def test_csv_has_units_and_the_samples(run_files, in_memory):
    _, _, C = run_files
    with C.open() as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    assert header[:2] == ["t [s]", "configuration"]
    for col in header[2:]:
        assert col.endswith("]") and " [" in col, col
    for col in ("theta_link3 [rad]", "omega_link3 [rad/s]", "x_link2 [m]", "kinetic_energy [J]",
                "potential_energy [J]", "force_tau1 [N m]"):
        assert col in header
    assert len(body) == len(in_memory.t)
    t = np.array([float(r[0]) for r in body])
    np.testing.assert_array_equal(t, in_memory.t)
    assert {r[1] for r in body} == {"config1", "config2"}
    i3 = header.index("theta_link3 [rad]")
    np.testing.assert_array_equal([float(r[i3]) for r in body], in_memory.series("theta", "link3"))
    # O3 exists only before the latch: its column is empty afterwards
    iq3 = header.index("q_O3 [rad]")  # a revolute joint: units from its type
    assert all((r[1] == "config1") == (r[iq3] != "") for r in body)
    assert "v_O3 [rad/s]" in header and not any("|" in h for h in header if h.startswith(("q_", "v_", "force_")))


@pytest.mark.parametrize("existing", ["--summary", "--out", "--csv"])
def test_existing_outputs_are_not_overwritten(tmp_path, capsys, existing):
    files = {"--summary": tmp_path / "s.json", "--out": tmp_path / "t.npz", "--csv": tmp_path / "c.csv"}
    files[existing].write_text("keep me")
    argv = ["run", SCENE, "--quiet"] + [x for k, p in files.items() for x in (k, p)]
    rc = cli(argv)
    out, err = capsys.readouterr()
    assert rc != 0
    assert str(files[existing]) in err and "--force" in err
    assert err.count("pcmm: error:") == 1 and "Traceback" not in err
    assert files[existing].read_bytes() == b"keep me"
    assert [p for k, p in files.items() if k != existing and p.exists()] == []  # nothing half-written
    assert cli(argv + ["--force"]) == 0
    assert files[existing].read_bytes() != b"keep me"


def test_no_impact_switch_keeps_surviving_velocities(tmp_path):
    S = tmp_path / "s.json"
    assert cli(["run", SCENE, "--no-impact", "--summary", S, "--quiet"]) == 0
    d = json.loads(S.read_text())
    assert d["impact"] is False
    ev = d["events"][0]
    assert ev["impact"] is False
    assert ev["impulse"] == {"normal": 0.0, "vector": [0.0, 0.0]}
    assert ev["joint_impulses"] == {}
    for j in ("O1", "O2"):
        assert ev["v_after"][j] == ev["v_before"][j]
    # without an impulse the same pre-switch state as with one (the switch is the first event)
    with_impact = pcmm.simulate(pcmm.load_scene(SCENE)).events[0]
    assert ev["t"] == with_impact["t"]
    assert ev["v_before"] == with_impact["v_before"]
    # the next configuration starts from those velocities
    traj = pcmm.simulate(pcmm.load_scene(SCENE), pcmm.RunOptions(impact=False))
    seg = traj.segments[1]
    assert seg.configuration == "config2"
    np.testing.assert_array_equal(seg.v[0], [ev["v_before"]["O1"], ev["v_before"]["O2"]])
    assert ev["dropped_velocities"]["O3"] == ev["v_before"]["O3"]


BAD_VALUES = [
    (["--t-end", "-1"], "t-end"),
    (["--t-end", "0"], "t-end"),
    (["--t-end", "nan"], "t-end"),
    (["--t-end", "inf"], "t-end"),
    (["--rtol", "0"], "rtol"),
    (["--rtol", "abc"], "rtol"),
    (["--atol=-1e-12"], "atol"),  # "=" form: argparse reads a bare "-1e-12" as an option
    (["--max-events", "0"], "max-events"),
    (["--step", "-0.001"], "step"),
    (["--accumulation-speed", "-1"], "accumulation-speed"),
]


@pytest.mark.parametrize("args,name", BAD_VALUES)
def test_out_of_range_cli_values_fail_cleanly(tmp_path, capsys, args, name):
    S = tmp_path / "s.json"
    rc = cli(["run", SCENE, "--summary", S, "--quiet", *args])
    out, err = capsys.readouterr()
    assert rc != 0
    assert name in err and args[-1].split("=")[-1] in err
    assert "Traceback" not in err + out
    assert not S.exists()


def test_run_options_out_of_range_raise_usage_error():
    """The library route refuses the same values (the CLI is not the only gate)."""
    scene = pcmm.load_scene(SCENE)
    for opts in (pcmm.RunOptions(t_end=-1.0), pcmm.RunOptions(rtol=0.0), pcmm.RunOptions(atol=math.nan)):
        with pytest.raises(pcmm.UsageError):
            pcmm.simulate(scene, opts)


@pytest.mark.parametrize("option", ["--summary", "--csv"])
def test_output_path_that_is_a_directory_fails_cleanly(tmp_path, capsys, option):
    target = tmp_path / "results"
    target.mkdir()
    rc = cli(["run", SCENE, option, target, "--quiet"])
    out, err = capsys.readouterr()
    assert rc != 0
    assert str(target) in err and err.count("pcmm: error:") == 1
    assert list(tmp_path.glob(".results.*")) == []  # no stray temporary file


def test_output_files_honour_the_umask(run_files):
    import os
    umask = os.umask(0)
    os.umask(umask)
    for p in run_files:
        assert p.stat().st_mode & 0o777 == 0o666 & ~umask, p


def test_quiet_keeps_the_warnings(tmp_path, capsys):
    """--quiet silences the progress bar and the event table, never a warning: Example 2 with
    B's velocity given at rest, which the loop replaces."""
    text = (EXAMPLES / "double_folded.toml").read_text().replace("../urdf/", f"{EXAMPLES.parent / 'urdf'}/")
    path = tmp_path / "v.toml"
    path.write_text(text.replace("v = { D = 0.0 }", "v = { B = 0.0, D = 0.0 }"))
    assert pcmm.cli.main(["run", str(path), "--quiet", "--t-end", "0.05", "--out", str(tmp_path / "r.npz")]) == 0
    captured = capsys.readouterr()
    assert "pcmm: warning:" in captured.err and "B given 0, now -0.363742" in captured.err
    assert "slider stop E" not in captured.out  # no event table or closest-approach lines


def test_every_command_help_says_what_the_command_does(capsys):
    """'pcmm NAME -h' opens with the line 'pcmm -h' lists for NAME (a newcomer's 'pcmm new -h'
    showed only the usage)."""
    import argparse
    parser = pcmm.cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    listed = {a.dest: a.help for a in sub._choices_actions}
    assert {"run", "new", "sweep", "optimize", "check"} <= set(listed)
    for name, text in listed.items():
        with pytest.raises(SystemExit):
            pcmm.cli.main([name, "-h"])
        out = capsys.readouterr().out
        assert text and " ".join(text.split()) in " ".join(out.split()), (name, out[:300])


def test_a_fallback_name_taken_meanwhile_moves_to_the_next_name_in_the_same_folder(tmp_path, monkeypatch):
    """Three runs started together on one --out (tests/test_fuzz.py's concurrent runs, failing
    once under load): two find r.npz taken and both pick r-2.npz; the one that loses that race
    must write r-3.npz beside it, not go on to the system's temporary folder (where the result
    was kept, but not where the user looks).  The race made deterministic: another run creates
    r-2.npz between this run's choice of the name and its write."""
    from pcmm import files
    monkeypatch.chdir(tmp_path)
    (tmp_path / "r.npz").write_bytes(b"the first run's")
    real = files.atomic_write

    def meanwhile(path, write, force, binary=False):
        if Path(path).name == "r-2.npz" and not Path(path).exists():
            Path(path).write_bytes(b"the second run's")  # the other run got there first
        return real(path, write, force, binary)
    monkeypatch.setattr(files, "atomic_write", meanwhile)
    kept = pcmm.cli._fallback(tmp_path / "r.npz", lambda p, force: files.atomic_write(p, lambda f: f.write(b"mine"), force, binary=True))
    assert Path(kept) == tmp_path / "r-3.npz" and Path(kept).read_bytes() == b"mine"
    assert (tmp_path / "r.npz").read_bytes() == b"the first run's" and (tmp_path / "r-2.npz").read_bytes() == b"the second run's"
