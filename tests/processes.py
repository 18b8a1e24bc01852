"""Child processes a test must catch in the middle of their work.

A study run in a subprocess is fast (a sweep row of the stop scene takes milliseconds since the
compiled loop), so a test that waits for a table's first rows and *then* starts a second sweep,
sends a signal or lists the workers raced the child to its end (CI at 57f9a16: the first sweep
had finished before the second one started, and the second took the table).  These helpers stop
the child (SIGSTOP) the moment the table has its rows, so whatever the test does next happens
while the child is, for certain, in the middle of its work; ``resume`` lets it go on.
"""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path


def lines(path: Path) -> int:
    """The number of lines of ``path`` so far (0 before it exists)."""
    try:
        return len(path.read_text().splitlines())
    except FileNotFoundError:
        return 0


def pause_at_lines(proc, path: Path, at_least: int, timeout: float = 120.0) -> int:
    """Wait until ``path`` has ``at_least`` lines, stop ``proc`` there and return its line count.

    Fails (naming the count) if the child ended first or the lines never came: the test could
    not then be about a child in the middle of its work."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout and lines(path) < at_least and proc.poll() is None:
        time.sleep(0.002)
    os.kill(proc.pid, signal.SIGSTOP)
    assert proc.poll() is None, f"the child ended before it was stopped ({lines(path)} lines in {path.name})"
    got = lines(path)
    assert got >= at_least, f"{path.name} had {got} lines after {timeout} s, waiting for {at_least}"
    return got


def resume(proc) -> None:
    """Let a child stopped by :func:`pause_at_lines` go on."""
    os.kill(proc.pid, signal.SIGCONT)
