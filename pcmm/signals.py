"""Signals: a batch scheduler's SIGTERM (or a closed terminal's SIGHUP) stops a command like
Ctrl-C does, and no interrupt cuts a result in half while it is being kept.

* :func:`as_interrupts` turns SIGTERM and SIGHUP into :class:`Terminated`, a
  ``KeyboardInterrupt``, so every ``except KeyboardInterrupt`` and ``finally`` that saves a
  partial run or stops the meshcat server also runs on them.
* :func:`deferred` holds SIGINT, SIGTERM and SIGHUP back while a block runs (recording the
  interrupted segment, writing the partial files): a second Ctrl-C then waits until the
  block is done instead of dropping what it was saving.
* :func:`hold` and :func:`release` do the same over a stretch that is no block: the command
  line's own imports, so a signal while ``pcmm`` starts is answered by ``main`` (a message,
  a partial result), not by Python's traceback.

Handlers can only be installed in the main thread; elsewhere both are no-ops.  A signal that
the process was started with ignored stays ignored (the Unix convention: ``nohup`` ignores SIGHUP,
a shell's background job SIGINT), so ``nohup pcmm run ...`` outlives the terminal it was started from.
"""
from __future__ import annotations

import _signal  # the C module under ``signal``: the same calls without its enum conversions
import contextlib
import signal
import threading

_NAMES = ("SIGINT", "SIGTERM", "SIGHUP")
#: their numbers on this platform (plain ints of the C module: what :func:`deferred` installs on)
_NUMBERS = tuple(getattr(_signal, n) for n in _NAMES if hasattr(_signal, n))


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised where a Ctrl-C would be."""

    def __init__(self, signum: int):
        super().__init__(f"signal {signum}")
        self.signum = signum


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _signals(names):
    """The signals of ``names`` this platform has and the process does not ignore (an ignored
    signal was ignored on purpose by whoever started it, ``nohup`` say: it is left so)."""
    out = []
    for n in names:
        sig = getattr(signal, n, None)
        if sig is None:
            continue
        with contextlib.suppress(ValueError, OSError):
            # _signal's, not signal.getsignal: that one turns the handler into an enum member
            # where it can, by raising and catching a ValueError for a Python handler (20 us per
            # signal, a tenth of Example 1's whole run went on these look-ups and settings)
            if _signal.getsignal(sig) == signal.SIG_IGN:
                continue
        out.append(sig)
    return out


def describe(exc: KeyboardInterrupt) -> str:
    signum = getattr(exc, "signum", None)
    return "interrupted by the user (Ctrl-C)" if signum is None else f"stopped by {signal.Signals(signum).name}"


def exit_status(exc: KeyboardInterrupt) -> int:
    """The shell's convention, 128 + the signal's number: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP."""
    return 128 + getattr(exc, "signum", signal.SIGINT)


@contextlib.contextmanager
def as_interrupts():
    """While the block runs, SIGTERM and SIGHUP raise :class:`Terminated`."""
    old = {}
    if _main_thread():
        def raise_terminated(signum, frame):
            raise Terminated(signum)
        for sig in _signals(("SIGTERM", "SIGHUP")):
            with contextlib.suppress(ValueError, OSError):
                old[sig] = signal.signal(sig, raise_terminated)
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


class _Held:
    """Signals held back: a handler that notes each one; as a context manager (:func:`deferred`)
    it holds them while the block runs."""

    def __init__(self):
        self.received: list[int] = []
        self.old: dict = {}

    def __call__(self, signum, frame):
        self.received.append(signum)

    def __enter__(self) -> "_Held":
        if _main_thread():  # every recorded segment passes here: the C module's calls (see _signals)
            old = self.old
            for sig in _NUMBERS:
                try:
                    if _signal.getsignal(sig) != _signal.SIG_IGN:  # ignored on purpose: left so
                        old[sig] = _signal.signal(sig, self)
                except (ValueError, OSError):
                    pass
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self.old.items():
            _signal.signal(sig, handler)
        self.old = {}

    def reraise(self) -> None:
        """Raise the first signal held back, as it would have been raised (if any arrived)."""
        if self.received:
            sig = self.received[0]
            raise KeyboardInterrupt() if sig == signal.SIGINT else Terminated(sig)


def hold() -> _Held:
    """Start holding SIGINT, SIGTERM and SIGHUP back now, until :func:`release` (for a stretch
    that is no block, such as a module's imports); a no-op outside the main thread."""
    held = _Held()
    if _main_thread():
        for sig in _signals(_NAMES):
            with contextlib.suppress(ValueError, OSError):
                held.old[sig] = signal.signal(sig, held)
    return held


def release(held: _Held) -> None:
    """Put back the handlers :func:`hold` replaced (the signals it held stay in ``received``)."""
    for sig, handler in held.old.items():
        with contextlib.suppress(ValueError, OSError, TypeError):
            signal.signal(sig, handler)
    held.old = {}


def deferred() -> _Held:
    """Hold interrupts back while the block runs; yields a record whose ``received`` lists the
    signals that arrived (the caller decides what they mean once the block is done).  A plain
    class's ``__enter__``/``__exit__`` on the signals' numbers (:data:`_NUMBERS`), not a generator's
    context manager on ``signal``'s enum members: every recorded segment passes here."""
    return _Held()


__all__ = ["Terminated", "as_interrupts", "deferred", "describe", "exit_status", "hold", "release"]
