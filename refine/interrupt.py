"""Ctrl-C that stops a run within a second, and sections that a signal cannot cut in half.

IPOPT runs inside CasADi, which checks Python's signal handlers between function evaluations: a
``KeyboardInterrupt`` raised there is caught by CasADi, IPOPT returns ``NonIpopt_Exception_Thrown``
and the run would go on as if nothing happened. :func:`stoppable` therefore makes the first SIGINT
(or SIGTERM) *sticky*: besides raising ``KeyboardInterrupt`` it starts a 50 ms interval timer whose
handler raises ``KeyboardInterrupt`` again, until one lands in plain Python code and unwinds the
run. The CLI catches it and exits with status 130 (128 + SIGINT).

Once the new output set is in place (:func:`outputs_complete`, called by
:meth:`refine.run.outputs.StagedOutputs.commit`), there is nothing left to stop: later signals inside
:func:`stoppable` are recorded but raise nothing, the run ends as it would have (the summary is
printed) and exits with its own status (0 ``ok``/``repaired``, 1 ``infeasible``).
:func:`completed_status` gives that status to a caller that catches a ``KeyboardInterrupt`` which
slipped in after the commit anyway (outside :func:`stoppable`).

:func:`deferred` blocks both signals around a section that must finish once started (moving the
finished outputs into place, removing a staging folder); a signal that arrives meanwhile is
delivered as soon as the section ends.

All of this is opt-in: a library call (``refine.solve``, ``refine.refine_path``,
``Result.write``) changes no timer, signal handler or signal mask of the process. The output
moves hold signals back (:func:`critical`) only inside :func:`guarded`, which :func:`stoppable`
(the ``refine`` command) enters; a host program may enter :func:`guarded` itself (main thread
only) to have its SIGINT, SIGTERM and SIGALRM held back while the files move.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext

REPEAT_S = 0.05
"""Interval of the repeated ``KeyboardInterrupt`` after the first signal [s]."""

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_state: dict = {"requested": False, "complete": None, "guarded": False}


def requested() -> bool:
    """Whether a stop has been asked for since :func:`install`."""
    return _state["requested"]


def outputs_complete(status: str) -> None:
    """Record that the run's new output set is in place, with its ``status``; stop the repeat timer.

    From here on a signal inside :func:`stoppable` raises nothing (module docstring). Outside
    :func:`guarded` (a library call) it records nothing; the process's timer is stopped only when
    it is the repeat timer a signal inside :func:`stoppable` started.
    """
    if not _state["guarded"]:
        return
    _state["complete"] = status
    repeating = _state["requested"]  # the repeat timer runs only after a signal inside stoppable
    _state["requested"] = False
    if repeating and threading.current_thread() is threading.main_thread():
        signal.setitimer(signal.ITIMER_REAL, 0.0, 0.0)


def forget_completion() -> None:
    """Start a new command: no output set of it is complete yet."""
    _state["complete"] = None


def completed_status() -> str | None:
    """The status of the run whose outputs are complete, or None while they are not."""
    return _state["complete"]


def _on_signal(signum: int, frame: object) -> None:
    if _state["complete"] is not None:
        return  # the outputs are complete: nothing to stop
    _state["requested"] = True
    signal.setitimer(signal.ITIMER_REAL, REPEAT_S, REPEAT_S)
    raise KeyboardInterrupt


def _on_alarm(signum: int, frame: object) -> None:
    if _state["requested"] and _state["complete"] is None:
        raise KeyboardInterrupt


@contextmanager
def stoppable() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM stop the run (module docstring); restored afterwards.

    Only in the main thread; a signal the parent process set to be ignored stays ignored.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {sig: signal.getsignal(sig) for sig in (*_SIGNALS, signal.SIGALRM)}
    for sig in _SIGNALS:
        if old[sig] is not signal.SIG_IGN:
            signal.signal(sig, _on_signal)
    signal.signal(signal.SIGALRM, _on_alarm)
    _state["requested"] = False
    _state["complete"] = None
    try:
        with guarded():
            yield
    finally:
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {*_SIGNALS, signal.SIGALRM})
        signal.setitimer(signal.ITIMER_REAL, 0.0, 0.0)
        _state["requested"] = False  # a pending alarm now does nothing
        for sig in _SIGNALS:
            signal.signal(sig, old[sig] if old[sig] is not None else signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
        signal.signal(signal.SIGALRM, old[signal.SIGALRM] or signal.SIG_DFL)


def hold_signals() -> None:
    """Ignore SIGINT and SIGTERM for the rest of the process (main thread only; else nothing).

    For a program about to exit: a signal that arrives now can no longer cut anything short, nor
    turn the exit into a traceback or a death by signal.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    signal.setitimer(signal.ITIMER_REAL, 0.0, 0.0)
    for sig in (*_SIGNALS, signal.SIGALRM):
        signal.signal(sig, signal.SIG_IGN)


@contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGALRM back while the block runs; deliver them afterwards.

    The signals' Python handlers are replaced by ones that only take note, and the first signal
    noted is raised again once the old handlers are back. (Blocking the signals in the main
    thread alone would not do: the kernel then hands them to another thread, and CPython may run
    the handler late or not at all.)
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []

    def note(signum: int, frame: object) -> None:
        noted.append(signum)

    old = {sig: signal.getsignal(sig) for sig in (*_SIGNALS, signal.SIGALRM)}
    for sig, handler in old.items():
        if handler is not signal.SIG_IGN:
            signal.signal(sig, note)
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        if noted:
            signal.raise_signal(noted[0])


@contextmanager
def guarded() -> Iterator[None]:
    """Within the block (main thread only), :func:`critical` sections hold signals back.

    Opt-in, for a program that owns the process's signals: the ``refine`` command enters it (through
    :func:`stoppable`); a host program may, around ``Result.write``. In another thread the block
    runs unguarded. Outside it no refine call touches a timer, signal handler or signal mask.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = _state["guarded"]
    _state["guarded"] = True
    try:
        yield
    finally:
        _state["guarded"] = before


def critical() -> AbstractContextManager[None]:
    """A section that must finish once started: :func:`deferred` inside :func:`guarded`, else plain.

    Unguarded, a signal's handler runs where it lands; the all-or-nothing outputs stay consistent
    nonetheless (:mod:`refine.run.outputs`).
    """
    if _state["guarded"] and threading.current_thread() is threading.main_thread():
        return deferred()
    return nullcontext()
