"""The state of a run between two steps of the paper's Fig. 3 loop."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..events.contact_laws import ContactPhase
from ..events.holding import Holds
from ..events.transitions import Context
from ..model.configuration import Configuration
from ..model.mechanism import Mechanism
from ..results.trajectory import Trajectory
from ..scene.settings import RunOptions
from ..scene.spec import Scene, TransitionSpec
from .audit import FlightAudit
from .guard_cache import GuardCache


@dataclass
class RunState:
    """Where a run is: the configuration and its state, and what the next segment must know.

    The fixed parts (scene, options, mechanism, record) come first; the loop variables after."""

    scene: Scene
    opts: RunOptions
    mech: Mechanism
    ctx: Context  # what the transitions read (impact or not, accumulation tolerances, last impacts)
    traj: Trajectory  # the record: segments, events, stats
    holds: Holds  # joints locked by latches and stop-merges, watched while they hold
    audit: FlightAudit
    cfg: Configuration
    t: float
    q: np.ndarray
    v: np.ndarray
    offsets: dict[str, float] = field(default_factory=dict)  # link -> 2 pi k its angle series continues with
    fired: set[str] = field(default_factory=set)  # the names of the events so far (a time guard fires once)
    phase: ContactPhase | None = None  # a collision resolved by a continuous contact law, under way
    bounced: TransitionSpec | None = None  # the stop that just bounced: its guard is re-armed
    y: np.ndarray | None = None  # the integrator's state where the last segment ended
    stepping: tuple | None = None  # (rhs, method, options) of the segment being integrated
    impulse_integral: float = 0.0  # the contact phase's impulse so far (N s), at the segment's end
    store: object = None  # a StoreWriter (pcmm.results.store): the record streamed to a folder as it goes
    # the guards kept from segment to segment by what they were built for (pcmm.run.loop._guards): a
    # bounce that follows a bounce at the same stop re-arms with them instead of building them again
    guard_cache: GuardCache = field(default_factory=GuardCache)
    # (configuration, release) whose reaction guard was said to start past its value
    # (pcmm.run.loop._releases_past_at_entry): each is said once
    releases_said: set = field(default_factory=set)

    @property
    def stats(self):
        return self.traj.stats
