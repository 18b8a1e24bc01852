"""The guards a run keeps from one segment to the next, by what they were built for.

A segment watches its configuration's guards (:func:`pcmm.run.loop._guards`): the transitions'
(the stop that just bounced re-armed), one per merge held by compression only, and the loop's
partition guard.  A bounce stays in its configuration, so the next segment would build the same
guards again; a run keeps them in a :class:`GuardCache` instead and builds only what changed:

* the **transitions' guards** (:meth:`GuardCache.transitions_for`), where every transition of the
  configuration watches a coordinate or a gap (functions of the state alone): they depend on the
  configuration, the bounced stop and the angle offsets (:meth:`Configuration.continue_angles`)
  only.  The last set, and up to :data:`MADE_GUARDS` sets of earlier stays (a cycle's next period,
  a bounce at the other stop of a configuration) by that key;
* the **merges' guards** (:meth:`GuardCache.merges_for`), while the run stays in the configuration
  with the same angle offsets and the same holds (the same ``Hold`` objects: a lock, a release or a
  switch makes new ones), outside a contact phase;
* the **whole list** of the last segment (:meth:`GuardCache.take_last`), where both sets above were
  taken or built for it: the next segment for the same configuration, bounced stop, offsets and
  holds takes it in one look-up (a bounce's re-arm);
* a flight's **guard copies** read on the first ``n`` components of the state
  (:meth:`GuardCache.on_state_for`), while the guards are the very same objects.

The keys hold the configuration, the bounced stop and the holds by identity (the same objects),
the offsets by value.  Nothing here builds a guard: the run loop builds them and hands them in.
"""
from __future__ import annotations

from dataclasses import dataclass, field

#: at most this many sets of transitions' guards kept per run (:attr:`GuardCache.made`): an angle
#: offset that grows with every turn of a link makes a new key at every turn
MADE_GUARDS = 64


@dataclass(slots=True)
class MergeGuards:
    """The merges' guards and what they were built for (:meth:`GuardCache.merges_for`)."""

    cfg: object  # the Configuration (the same object)
    offsets: tuple  # its angle offsets, sorted (link, 2 pi k) pairs
    holds: tuple  # the Hold objects in force (the same objects; a copy of the holds' list)
    guards: tuple


@dataclass(slots=True)
class LastList:
    """The whole guard list of the last segment (without the coordinates' own) and what it was
    built for (:meth:`GuardCache.take_last`)."""

    cfg: object
    bounced: object  # the transition of the stop that bounced (the same object), or None
    offsets: tuple
    holds: tuple
    guards: list


@dataclass(slots=True)
class OnStateCopies:
    """A flight's guards read on the first ``n`` components of the state (:meth:`GuardCache.on_state_for`)."""

    guards: tuple  # the guards copied (the same objects)
    n: int
    copies: tuple


@dataclass(slots=True)
class GuardCache:
    """The run's kept guards (one per run, :attr:`pcmm.run.state.RunState.guard_cache`).

    ``transitions_key`` and ``transitions``: the transitions' guards of the last segment and the
    ``(configuration, bounced stop, offsets)`` they were built for (None and ``()`` where they
    cannot be kept: a time or reaction guard, a contact phase).  ``merges``, ``last``,
    ``on_state``: see :class:`MergeGuards`, :class:`LastList`, :class:`OnStateCopies`.  ``made``:
    the transitions' guards of earlier stays, ``{(id(cfg), id(bounced), offsets): (cfg, bounced,
    guards)}`` (the objects held, so their ids stay theirs while kept)."""

    transitions_key: tuple | None = None
    transitions: tuple = ()
    merges: MergeGuards | None = None
    last: LastList | None = None
    on_state: OnStateCopies | None = None
    made: dict = field(default_factory=dict)

    # -- the whole list ------------------------------------------------------------------------

    def take_last(self, cfg, bounced, offsets, holds) -> list | None:
        """The last segment's whole list where it was built for the same configuration, bounced
        stop, offsets and holds (``holds``: the ``Hold`` objects in force), else None.  The kept list
        itself, read only: the caller makes its own (``+``).  (Replacing either kept set forgets it,
        so the list kept is always the one the kept sets standing now made.)"""
        last = self.last
        if last is None or last.cfg is not cfg or last.bounced is not bounced or last.offsets != offsets:
            return None
        kept = last.holds
        if len(kept) != len(holds) or not all(a is b for a, b in zip(kept, holds)):
            return None
        return last.guards

    def keep_last(self, cfg, bounced, offsets, holds, guards: list) -> None:
        """Keep ``guards`` as the whole list for the next segment, where both kept sets stand for
        this segment (taken or built now, outside a contact phase); else forget the last list."""
        if self.transitions_key is not None and self.merges is not None:
            self.last = LastList(cfg, bounced, offsets, tuple(holds), guards[:])
        else:
            self.last = None

    # -- the transitions' guards ---------------------------------------------------------------

    def transitions_for(self, cfg, bounced, offsets) -> tuple | None:
        """The transitions' guards built for this configuration, bounced stop and offsets: the last
        segment's, else an earlier stay's (:attr:`made`, then the last set again), else None."""
        key = self.transitions_key
        if key is not None and key[0] is cfg and key[1] is bounced and key[2] == offsets:
            return self.transitions
        made = self.made_for(cfg, bounced, offsets)
        if made is not None:  # built at an earlier stay in cfg, for the same bounced stop and offsets
            self.transitions_key, self.transitions, self.last = (cfg, bounced, offsets), made, None
        return made

    def keep_transitions(self, cfg, bounced, offsets, guards: tuple | None) -> None:
        """Keep the transitions' guards just built (None: they cannot be kept, the last set is
        forgotten), as the last set and among :attr:`made`."""
        self.last = None
        if guards is None:
            self.transitions_key, self.transitions = None, ()
            return
        self.transitions_key, self.transitions = (cfg, bounced, offsets), guards
        self.keep_made(cfg, bounced, offsets, guards)

    def made_for(self, cfg, bounced, offsets) -> tuple | None:
        """The transitions' guards kept among :attr:`made` for this configuration, bounced stop and
        offsets, or None."""
        entry = self.made.get((id(cfg), id(bounced), offsets))
        return entry[2] if entry is not None and entry[0] is cfg and entry[1] is bounced else None

    def keep_made(self, cfg, bounced, offsets, guards: tuple) -> None:
        """Keep ``guards`` among :attr:`made` (all forgotten first where :data:`MADE_GUARDS` are kept)."""
        if len(self.made) >= MADE_GUARDS:
            self.made.clear()
        self.made[(id(cfg), id(bounced), offsets)] = (cfg, bounced, guards)

    # -- the merges' guards --------------------------------------------------------------------

    def merges_for(self, cfg, offsets, holds) -> tuple | None:
        """The merges' guards of the last segment where they were built for the same configuration,
        offsets and holds, else None."""
        kept = self.merges
        if kept is None or kept.cfg is not cfg or kept.offsets != offsets:
            return None
        if len(kept.holds) != len(holds) or not all(a is b for a, b in zip(kept.holds, holds)):
            return None
        return kept.guards

    def keep_merges(self, cfg, offsets, holds, guards: tuple | None) -> None:
        """Keep the merges' guards just built (None: built in a contact phase, not kept)."""
        self.last = None
        self.merges = None if guards is None else MergeGuards(cfg, offsets, tuple(holds), guards)

    # -- a flight's guard copies ---------------------------------------------------------------

    def on_state_for(self, guards: list, n: int) -> tuple | None:
        """The copies of ``guards`` read on ``n`` components kept for the very same guard objects, or None."""
        kept = self.on_state
        if kept is None or kept.n != n or len(kept.guards) != len(guards):
            return None
        return kept.copies if all(a is b for a, b in zip(kept.guards, guards)) else None

    def keep_on_state(self, guards: list, n: int, copies: list) -> None:
        self.on_state = OnStateCopies(tuple(guards), n, tuple(copies))
