"""A plain ``pcmm run`` imports only what it uses (issue 26, item 4: start-up within 2x of
``import pinocchio``; benchmarks/startup.py measures it).  Timings are not asserted: what is
asserted is the list of modules a run leaves in ``sys.modules``, so a module-level import of a
view, a study backend or a scipy package that the run does not need fails here instead of
silently costing the start-up again.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Run the command line's own entry point, then list every module the process imported.
_DUMP = """
import json, sys
from pcmm.cli import main
try:
    code = main(sys.argv[2:])
finally:
    with open(sys.argv[1], "w") as fh:
        json.dump(sorted(sys.modules), fh)
sys.exit(code)
"""

# Optional extras and views a plain run must not load (figures only with --plots, the replay
# only with --replay, a progress bar only on a terminal, dask/pyarrow/zarr only for studies).
NEVER = ("matplotlib", "meshcat", "tqdm", "dask", "distributed", "pyarrow", "zarr", "pandas",
         "pcmm.viz", "pcmm.studies")


def modules_of_run(tmp_path, *args) -> list[str]:
    out = tmp_path / "modules.json"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))
    proc = subprocess.run([sys.executable, "-c", _DUMP, str(out), "run", *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(out.read_text())


def loaded(modules, prefix) -> list[str]:
    return [m for m in modules if m == prefix or m.startswith(prefix + ".")]


@pytest.fixture(scope="module")
def plain_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("startup")
    return modules_of_run(tmp, str(ROOT / "examples" / "three_bar.toml"), "--out", str(tmp / "run"), "--quiet")


@pytest.mark.parametrize("name", NEVER)
def test_plain_run_does_not_import(plain_run, name):
    assert not loaded(plain_run, name), f"a plain 'pcmm run' imported {loaded(plain_run, name)[:5]}"


def test_the_dump_sees_what_a_run_imports(plain_run):
    """The dump is real: the run's own modules (Pinocchio, the run loop) are in it."""
    assert "pinocchio" in plain_run and "pcmm.run.loop" in plain_run and "numpy" in plain_run
