"""The Python evaluations stay a working path: every shipped example with the compiled ones off.

Where pip found no C++ compiler, or with ``PCMM_COMPILED=0``, every right-hand side, closure row and
segment loop is Python's.  The suite runs on the compiled path, so this file keeps the other one
green in every run of it: each shipped example's first stretch (0.2 s, a tenth of Andrews' run),
run with ``PCMM_COMPILED=0`` set in this process, must build no compiled object and give the
compiled run's events (the same names, times to 1e-9 s) and end state (1e-7).  The two right-hand
sides agree to round-off (tests/test_compiled.py), so the runs may differ only by its growth.
The whole suite on the Python path (docs/development.md):

    PCMM_COMPILED=0 python -m pytest -q -n auto
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.model import compiled

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.toml"))


def _run(path: Path, t_end: float):
    compiled.forget_trees()
    traj = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=t_end))
    return traj, compiled.trees_built()


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda p: p.name)
def test_every_example_runs_on_the_python_evaluations(example, monkeypatch):
    t_end = tomllib.loads(example.read_text())["scene"]["t_end"]
    t_end = min(0.2, t_end / 10) if t_end < 0.2 else 0.2  # Example 1 latches at 0.167 s
    if compiled.enabled():
        fast, _ = _run(example, t_end)
    else:  # this whole process runs Python's: nothing to compare against
        fast = None
    monkeypatch.setenv(compiled.ENV, "0")
    slow, built = _run(example, t_end)
    assert built == 0, "a compiled object was built with PCMM_COMPILED=0"
    assert compiled.why_not() is not None and "PCMM_COMPILED" in compiled.why_not()
    assert slow.status == "complete" and slow.t[-1] == pytest.approx(t_end, abs=1e-12)
    if fast is None:
        return
    assert [e["name"] for e in slow.events] == [e["name"] for e in fast.events]
    for a, b in zip(slow.events, fast.events):
        assert abs(a["t"] - b["t"]) <= 1e-9, (a["name"], a["t"], b["t"])
    a, b = slow.segments[-1], fast.segments[-1]
    assert a.configuration == b.configuration
    np.testing.assert_allclose(a.q[-1], b.q[-1], rtol=0, atol=1e-7)
    np.testing.assert_allclose(a.v[-1], b.v[-1], rtol=0, atol=1e-7)
