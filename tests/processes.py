"""Child processes a test must catch in the middle of their work.

A study run in a subprocess is fast (a sweep row of the stop scene takes milliseconds since the
compiled loop), so a test that waits for a table's first rows and *then* starts a second sweep,
sends a signal or lists the workers raced the child to its end (CI at 57f9a16: the first sweep
had finished before the second one started, and the second took the table).  Stopping the child
(SIGSTOP) once the test saw the rows only narrowed the race: the child goes on between the test's
look at the table and the signal, and on a machine ten times faster the rest of a sweep fits in
that gap.  So the child stops *itself*: started by :func:`held_cli`, a study's own process (not its
workers) waits, right after its table took ``rows`` rows, until the test opens the gate
(:func:`study_hooks.hold_table`); :meth:`Gate.wait_held` returns once it waits there, so whatever
the test does next happens while the child is, for certain, in the middle of its work.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent

#: the environment variable :func:`study_hooks.hold_table` reads: ``ROWS:FOLDER``
HOLD_ENV = "PCMM_TEST_HOLD"

#: ``pcmm`` (``python -m pcmm.cli``) with :func:`study_hooks.hold_table` installed first
_HELD_MAIN = "import sys, study_hooks; study_hooks.hold_table(); from pcmm.cli import main; sys.exit(main(sys.argv[1:]))"


class Gate:
    """Where a study run by :func:`held_cli` stops itself after ``rows`` rows: it writes
    ``folder/held`` (the rows its table had) and waits until ``folder/go`` exists."""

    def __init__(self, folder: Path, rows: int):
        self.folder, self.rows = Path(folder), rows
        self.folder.mkdir(parents=True, exist_ok=True)

    def env(self) -> dict:
        """The environment of a child that stops at this gate (it imports pcmm from this tree)."""
        path = os.pathsep.join(p for p in (str(ROOT), str(TESTS), os.environ.get("PYTHONPATH")) if p)
        return {**os.environ, "PYTHONPATH": path, HOLD_ENV: f"{self.rows}:{self.folder}"}

    def wait_held(self, proc, timeout: float = 300.0) -> int:
        """Wait until ``proc`` stopped at the gate; the rows its table had then.  Fails, with the
        child's error output, if it ended first (it could not then be caught mid-way)."""
        held = self.folder / "held"
        end = time.monotonic() + timeout
        while not held.exists():
            if proc.poll() is not None:
                err = proc.stderr.read() if proc.stderr else ""
                raise AssertionError(f"the child ended (status {proc.returncode}) before its table had "
                                     f"{self.rows} rows: {err}")
            assert time.monotonic() < end, f"the child did not reach {self.rows} rows in {timeout} s"
            time.sleep(0.01)
        return int(held.read_text())

    def open(self) -> None:
        """Let the child go on."""
        (self.folder / "go").touch()


def held_cli(args, gate: Gate, **popen_kw):
    """``python -m pcmm.cli ARGS`` that stops at ``gate`` (stdout and stderr piped, as text)."""
    import subprocess
    return subprocess.Popen([sys.executable, "-c", _HELD_MAIN, *map(str, args)], env=gate.env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen_kw)
