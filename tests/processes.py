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
the test does next happens while the child is, for certain, in the middle of its work.  Likewise a
``pcmm run`` started by :func:`marked_cli` says when it has recorded its first segment.
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

#: the environment variable :func:`study_hooks.mark_recorded` reads: the marker file's path
MARK_ENV = "PCMM_TEST_MARK"


def child_env(**extra: str) -> dict:
    """The environment of a child that imports pcmm from this tree and the suite's hooks."""
    path = os.pathsep.join(p for p in (str(ROOT), str(TESTS), os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}


def hooked_cli(hook: str, args, env: dict, **popen_kw):
    """``python -m pcmm.cli ARGS`` with ``study_hooks.HOOK()`` called first (stdout and stderr
    piped, as text)."""
    import subprocess
    main = f"import sys, study_hooks; study_hooks.{hook}(); from pcmm.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.Popen([sys.executable, "-c", main, *map(str, args)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen_kw)


def wait_for_file(proc, path: Path, what: str, timeout: float = 300.0) -> None:
    """Wait until ``path`` exists (the child's handshake); fails, with the child's error output,
    if the child ended first."""
    end = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            err = proc.stderr.read() if proc.stderr else ""
            raise AssertionError(f"the child ended (status {proc.returncode}) before {what}: {err}")
        assert time.monotonic() < end, f"the child did not reach {what} in {timeout} s"
        time.sleep(0.01)


class Gate:
    """Where a study run by :func:`held_cli` stops itself after ``rows`` rows: it writes
    ``folder/held`` (the rows its table had) and waits until ``folder/go`` exists."""

    def __init__(self, folder: Path, rows: int):
        self.folder, self.rows = Path(folder), rows
        self.folder.mkdir(parents=True, exist_ok=True)

    def env(self) -> dict:
        """The environment of a child that stops at this gate."""
        return child_env(**{HOLD_ENV: f"{self.rows}:{self.folder}"})

    def wait_held(self, proc, timeout: float = 300.0) -> int:
        """Wait until ``proc`` stopped at the gate; the rows its table had then.  Fails if it
        ended first (it could not then be caught mid-way)."""
        wait_for_file(proc, self.folder / "held", f"its table had {self.rows} rows", timeout)
        return int((self.folder / "held").read_text())

    def open(self) -> None:
        """Let the child go on."""
        (self.folder / "go").touch()


def held_cli(args, gate: Gate, **popen_kw):
    """``python -m pcmm.cli ARGS`` that stops at ``gate`` (stdout and stderr piped, as text)."""
    return hooked_cli("hold_table", args, gate.env(), **popen_kw)


def marked_cli(args, marker: Path, **popen_kw):
    """``python -m pcmm.cli run ...`` that creates ``marker`` once it recorded its first segment:
    a signal sent after :func:`wait_for_file` finds it lands in the run, past its start-up, for
    certain (a wait for some seconds of CPU assumed how much start-up costs)."""
    return hooked_cli("mark_recorded", args, child_env(**{MARK_ENV: str(marker)}), **popen_kw)
