"""User-facing errors.

Every error a user can cause is one of these.  Each carries a list of
problems; every problem names the file, the field or element, the bad value
and what is allowed.  The CLI prints them and exits non-zero, never a
traceback.
"""
from __future__ import annotations


class PcmmError(Exception):
    """Base class: a list of human-readable problems, each self-contained."""

    exit_code = 2

    def __init__(self, problems: str | list[str]):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__(self.text())

    def text(self) -> str:
        if len(self.problems) == 1:
            return self.problems[0]
        return f"{len(self.problems)} problems:\n" + "\n".join(f"  - {p}" for p in self.problems)


class SceneError(PcmmError):
    """The scene file (TOML) is malformed or inconsistent."""


class ModelError(PcmmError):
    """A URDF file is malformed, not planar, or has bad inertia."""


class SimulationError(PcmmError):
    """The run cannot continue honestly (singular posture, persistent contact, ...).

    ``partial`` may hold the trajectory up to the failure so no result is lost.
    """

    exit_code = 3

    def __init__(self, problems, partial=None):
        super().__init__(problems)
        self.partial = partial


class UsageError(PcmmError):
    """A command-line value is out of range."""


class OutputError(PcmmError):
    """The operating system refused to write a result (read-only or full folder, a file-size
    limit).  The results are still in memory; the command line writes them elsewhere and says where."""

    exit_code = 4

    def __init__(self, path, exc: OSError):
        self.path, self.reason = path, exc
        why = exc.strerror or str(exc)
        super().__init__(f"{path}: cannot write it: {why} (errno {exc.errno})" if exc.errno
                         else f"{path}: cannot write it: {exc}")


class Repartition(Exception):
    """Internal: a loop's dependent coordinates became ill-conditioned mid-segment;
    the run restarts the segment with a new partition (never reaches the user)."""
