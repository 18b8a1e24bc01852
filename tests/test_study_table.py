"""The results table of a study as a record (issue 25, item 1): rows written whole and checked
on resume, the table locked for a sweep, links refused, text cells neutralised as ``run --csv``
does them, file-system failures a message with exit 4, hostile names shown and drawn literally,
SIGTERM exit 143."""
from __future__ import annotations

import csv
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import pcmm
from pcmm.cli import main
from pcmm.errors import OutputError, UsageError
from pcmm.results.trajectory import spreadsheet_text
from pcmm.studies.sweep import Axis, ResultsTable, columns, make_plan, sweep
from pcmm.studies.table import cell, checksum

from builders import EXAMPLES
from processes import Gate, held_cli

ROOT = Path(__file__).resolve().parents[1]
STOP = EXAMPLES / "three_bar_stop.toml"
PATH = "transitions.O3 stop.restitution"


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def hostile_scene(folder: Path) -> Path:
    """Example 1 with the stop, its names made hostile: a scene name with ESC and BEL, the
    merged configuration named '=1+2' (a spreadsheet formula), the stop named 't$\\oops$'
    (matplotlib mathtext that does not parse)."""
    text = STOP.read_text().replace("../urdf", str(ROOT / "urdf"))
    text = text.replace('name = "three_bar_stop"', 'name = "stop\\u001b[31m\\u0007"')
    text = text.replace("[configurations.config2]", '[configurations."=1+2"]')
    text = text.replace('merge_to = "config2"', 'merge_to = "=1+2"')
    text = text.replace('name = "O3 stop"', "name = 't$\\oops$'")
    path = folder / "hostile.toml"
    path.write_text(text)
    return path


def test_a_row_cut_in_its_last_number_is_dropped_and_run_again(tmp_path):
    # the case: a kill during the write keeps '-0.1283817460440' of '-0.12838174604406127',
    # a row with every cell present; its checksum no longer matches
    scene = pcmm.load_scene(STOP)
    plan = make_plan([Axis(PATH, (0.5, 0.8))])
    out = tmp_path / "r.csv"
    sweep(scene, plan, out, pcmm.RunOptions(t_end=0.2), workers=1)
    whole = out.read_text()
    head, last = whole.rstrip("\n").rsplit("\n", 1)
    cells = last.split(",")
    assert len(cells[-1]) == 8 and cells[-1] == checksum(cells[:-1])
    before = read(out)
    out.write_text(head + "\n" + last[:-5])  # cut inside the checksum: every cell still there
    res = sweep(scene, plan, out, pcmm.RunOptions(t_end=0.2), workers=1, resume=True)
    assert (res.skipped, res.ran) == (1, 1)
    assert len(res.dropped) == 1 and "line 3 (run 1): cut short or altered" in res.dropped[0]
    timed = ("solve_s", "wall_s", "check")
    assert [{k: v for k, v in r.items() if k not in timed} for r in read(out)] == \
        [{k: v for k, v in r.items() if k not in timed} for r in before]  # the same rows, wall times aside
    # a number altered in place (same length) is caught too
    rows = out.read_text().split("\n")
    rows[1] = rows[1].replace("0.5,", "0.6,", 1)
    out.write_text("\n".join(rows))
    res = sweep(scene, plan, out, pcmm.RunOptions(t_end=0.2), workers=1, resume=True)
    assert (res.skipped, res.ran, len(res.dropped)) == (1, 1, 1)
    assert sorted(r[PATH] for r in read(out)) == ["0.5", "0.8"]


def test_the_table_is_locked_for_the_length_of_a_sweep(tmp_path):
    scene = pcmm.load_scene(STOP)
    plan = make_plan([Axis(PATH, (0.5, 0.8))])
    out = tmp_path / "r.csv"
    holder = ResultsTable(out, columns(plan.paths, []), 1, resume=False, force=False)
    try:
        with pytest.raises(UsageError, match="another pcmm sweep is writing this table"):
            sweep(scene, plan, out, pcmm.RunOptions(t_end=0.2), workers=1, resume=True)
    finally:
        holder.close()
    res = sweep(scene, plan, out, pcmm.RunOptions(t_end=0.2), workers=1, resume=True)
    assert res.ran == 2


def _sweep_cli(args, cwd, **kw):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "pcmm.cli", "sweep", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


@pytest.mark.slow  # two concurrent sweeps in subprocesses
def test_two_resumes_at_once_give_each_run_once(tmp_path):
    # the probe: two --resume on one table gave 33 rows for 18 runs.  Each run goes to
    # 1.0 s (past the stop's impact at 0.167 s); the first sweep waits after its first row (a
    # gate, processes.py) while the second starts: the whole rest of a sweep once fitted in the
    # second's start-up (CI at 57f9a16)
    args = [str(STOP), "--set", f"{PATH}=0.1:0.9:17", "--t-end", "1.0", "--out", "r.csv", "--workers", "1",
            "--quiet"]
    gate = Gate(tmp_path / "gate", rows=1)
    first = held_cli(["sweep", *args], gate, cwd=tmp_path)
    out = tmp_path / "r.csv"
    assert gate.wait_held(first) == 1  # the first sweep holds the table, stopped mid-way (16 runs left)
    second = _sweep_cli([*args, "--resume"], tmp_path)
    err2 = second.communicate(timeout=120)[1]
    assert len(read(out)) == 1  # the second one ran while the first had runs left
    gate.open()
    first.communicate(timeout=120)
    assert first.returncode == 0
    assert second.returncode == 2 and "another pcmm sweep is writing this table" in err2
    third = _sweep_cli([*args, "--resume"], tmp_path)
    third.communicate(timeout=120)
    rows = read(out)
    assert len(rows) == len({r[PATH] for r in rows}) == 17


def test_a_link_is_refused_and_its_target_untouched(tmp_path, capsys):
    target = tmp_path / "precious.txt"
    target.write_text("keep me\n")
    link = tmp_path / "r.csv"
    link.symlink_to(target)
    code = main(["sweep", str(STOP), "--set", f"{PATH}=0.5", "--t-end", "0.2", "--out", str(link), "--force",
                 "--workers", "1", "--quiet"])
    err = capsys.readouterr().err
    assert code == 4 and f"{link}: cannot write it: is a symbolic link (to {target})" in err
    assert target.read_text() == "keep me\n" and link.is_symlink()
    dangling = tmp_path / "d.csv"
    dangling.symlink_to(tmp_path / "nowhere" / "x.csv")
    code = main(["sweep", str(STOP), "--set", f"{PATH}=0.5", "--t-end", "0.2", "--out", str(dangling),
                 "--workers", "1", "--quiet"])
    err = capsys.readouterr().err
    assert code == 4 and f"{dangling}: cannot write it: is a symbolic link" in err
    assert "Traceback" not in err


def test_cells_are_neutralised_by_the_function_run_csv_uses():
    # one function: the table's text cells are exactly spreadsheet_text's, numbers are their own text
    for text in ("=1+2", "+cmd", "-2+3", "@SUM(A1)", "\tx", "config1", ""):
        assert cell(text) == spreadsheet_text(text)
    assert cell("=1+2") == "'=1+2" and cell(-0.12838174604406127) == "-0.12838174604406127"
    assert cell(None) == "" and cell(True) == "true" and cell(3) == "3"


@pytest.mark.slow  # sweeps and figures under hostile names
def test_hostile_names_in_the_table_the_terminal_and_the_figures(tmp_path):
    scene = hostile_scene(tmp_path)
    path = "transitions.t$\\oops$.restitution"
    proc = _sweep_cli([str(scene), "--set", f"{path}=0.0,0.3", "--t-end", "0.5", "--out", "t.csv",
                       "--collect", "configuration_final", "--plots", "figs", "--workers", "1", "--quiet"], tmp_path)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert "\x1b" not in out + err and "\x07" not in out + err
    assert "stop\\x1b[31m\\x07: 2 runs planned" in out
    rows = read(tmp_path / "t.csv")
    # e = 0: a plastic stop merges into '=1+2' at the first impact; the cell is text, not a formula
    plastic = next(r for r in rows if r[path] == "0.0")
    assert plastic["configuration_final"] == "'=1+2"
    assert not any(v.startswith(("=", "+", "@")) for r in rows for v in r.values())
    figures = sorted(p.name for p in (tmp_path / "figs").iterdir())
    assert "peak_impulse__vs__transitions.t_oops_.restitution.png" in figures


@pytest.mark.skipif(not hasattr(resource, "RLIMIT_FSIZE"), reason="no file-size limit on this system")
def test_a_full_disk_is_a_message_with_the_path_and_exit_4(tmp_path):
    # a file-size limit stands in for a full disk: the write fails part-way (EFBIG) like ENOSPC
    header = len(",".join(columns([PATH], [])).encode()) + 1

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (header + 250, header + 250))
    proc = _sweep_cli([str(STOP), "--set", f"{PATH}=0.1:0.9:5", "--t-end", "0.2", "--out", "r.csv",
                       "--workers", "1", "--quiet"], tmp_path, preexec_fn=limit)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 4, err
    assert f"r.csv: cannot write it: File too large (errno 27)" in err and "Traceback" not in err
    res = sweep(pcmm.load_scene(STOP), make_plan([Axis(PATH, (0.1, 0.3, 0.5, 0.7, 0.9))]), tmp_path / "r.csv",
                pcmm.RunOptions(t_end=0.2), workers=1, resume=True)
    assert len(res.dropped) == 1 and res.skipped + res.ran == 5  # the row cut by the limit, run again
    assert len(read(tmp_path / "r.csv")) == 5


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_folder_is_a_message_with_exit_4(tmp_path, capsys):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        code = main(["sweep", str(STOP), "--set", f"{PATH}=0.5", "--out", str(folder / "r.csv"), "--workers", "1",
                     "--quiet"])
    finally:
        folder.chmod(0o700)
    err = capsys.readouterr().err
    assert code == 4 and str(folder) in err and "Traceback" not in err


def test_sigterm_exits_143(tmp_path):
    args = [str(STOP), "--set", f"{PATH}=0.1:0.9:9", "--t-end", "1.0", "--out", "r.csv", "--workers", "1",
            "--quiet"]
    gate = Gate(tmp_path / "gate", rows=1)
    proc = held_cli(["sweep", *args], gate, cwd=tmp_path)
    assert gate.wait_held(proc) == 1  # stopped mid-sweep, 8 runs left
    proc.send_signal(signal.SIGTERM)
    gate.open()  # (a SIGTERM held until the wait ends stops it all the same)
    _, err = proc.communicate(timeout=60)
    assert len(read(tmp_path / "r.csv")) < 9
    assert proc.returncode == 143 and "stopped by SIGTERM" in err and "--resume" in err
