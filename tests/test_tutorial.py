"""docs/tutorial.md runs as written: every fenced block is extracted and executed in a fresh
folder, in order: ``file=NAME`` blocks are written, ``sh`` blocks run line by line as ``pcmm``
commands (each must exit 0), ``python`` blocks are executed.  The tutorial cannot rot."""
from __future__ import annotations

import re
import shlex

import pytest

import pcmm.cli
from builders import ROOT

TUTORIAL = ROOT / "docs" / "tutorial.md"
FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```", re.S | re.M)


def blocks():
    return [(lang, info.strip(), body) for lang, info, body in FENCE.findall(TUTORIAL.read_text())]


def test_the_tutorial_has_its_parts():
    kinds = [(lang, info) for lang, info, _ in blocks()]
    assert ("xml", "file=arm_free.urdf") in kinds and ("xml", "file=arm_latched.urdf") in kinds
    assert ("toml", "file=arm.toml") in kinds
    assert sum(lang == "sh" for lang, _ in kinds) >= 2 and sum(lang == "python" for lang, _ in kinds) >= 1
    text = TUTORIAL.read_text()
    assert '"pi/6"' in text and '"30 deg"' in text and "figures/conventions.png" in text
    assert (ROOT / "docs" / "figures" / "conventions.png").is_file()


@pytest.mark.slow  # every block of the tutorial, its runs and figures
def test_every_block_of_the_tutorial_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    pytest.importorskip("matplotlib")  # the tutorial writes figures
    ran = []
    for lang, info, body in blocks():
        name = re.search(r"file=(\S+)", info)
        if name:
            (tmp_path / name.group(1)).write_text(body)
            ran.append(name.group(1))
        elif lang == "sh":
            for line in body.splitlines():
                line = line.split("#")[0].strip()
                if not line:
                    continue
                argv = shlex.split(line)
                assert argv[0] == "pcmm", f"tutorial command is not a pcmm command: {line}"
                rc = pcmm.cli.main(argv[1:])
                assert rc == 0, f"{line!r} exited {rc}: {capsys.readouterr().err}"
                ran.append(line)
        elif lang == "python":
            exec(compile(body, f"{TUTORIAL}:python", "exec"), {"__name__": "tutorial"})
            ran.append("python")
    assert "pcmm check arm.toml" in ran and "python" in ran
    out = capsys.readouterr().out
    assert "latch at t = 0.13" in out
    assert "<visual>" not in out  # pcmm check: every bar of the tutorial's URDFs is drawn
    for f in ("summary.json", "run.npz", "run.csv", "replay.html", "figures/link_angles.png"):
        assert (tmp_path / f).is_file(), f
