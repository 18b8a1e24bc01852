"""What the views read of a recorded run, and how they mark its events."""
from __future__ import annotations

from typing import Protocol


def event_kind(ev: dict) -> str:
    """The kind of an event record, as the views mark it: ``release``, ``merge``, ``impact`` or
    ``switch`` (a configuration change without impact)."""
    if ev.get("transition") == "release":
        return "release"
    if ev.get("merge"):
        return "merge"
    if ev.get("impact"):
        return "impact"
    return "switch"


class RecordedRun(Protocol):
    """What the views read of a run: its record alone (a
    :class:`pcmm.results.trajectory.Trajectory` is one, saved or fresh)."""

    scene_name: str
    source: str | None
    impact: bool
    segments: list
    events: list[dict]
    views: dict

    @property
    def t(self): ...

    @property
    def links(self) -> list[str]: ...

    def series(self, quantity: str, name: str | None = None): ...
