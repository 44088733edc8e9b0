"""Ctrl-C that stops a run within a second, and sections that a signal cannot cut in half.

IPOPT runs inside CasADi, which checks Python's signal handlers between function evaluations: a
``KeyboardInterrupt`` raised there is caught by CasADi, IPOPT returns ``NonIpopt_Exception_Thrown``
and the run would go on as if nothing happened. :func:`stoppable` therefore makes the first SIGINT
(or SIGTERM) *sticky*: besides raising ``KeyboardInterrupt`` it starts a 50 ms interval timer whose
handler raises ``KeyboardInterrupt`` again, until one lands in plain Python code and unwinds the
run. The CLI catches it and exits with status 130 (128 + SIGINT).

:func:`deferred` blocks both signals around a section that must finish once started (moving the
finished outputs into place, removing a staging folder); a signal that arrives meanwhile is
delivered as soon as the section ends.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

REPEAT_S = 0.05
"""Interval of the repeated ``KeyboardInterrupt`` after the first signal [s]."""

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_state = {"requested": False}


def requested() -> bool:
    """Whether a stop has been asked for since :func:`install`."""
    return _state["requested"]


def _on_signal(signum: int, frame: object) -> None:
    _state["requested"] = True
    signal.setitimer(signal.ITIMER_REAL, REPEAT_S, REPEAT_S)
    raise KeyboardInterrupt


def _on_alarm(signum: int, frame: object) -> None:
    if _state["requested"]:
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
    try:
        yield
    finally:
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {*_SIGNALS, signal.SIGALRM})
        signal.setitimer(signal.ITIMER_REAL, 0.0, 0.0)
        _state["requested"] = False  # a pending alarm now does nothing
        for sig in _SIGNALS:
            signal.signal(sig, old[sig] if old[sig] is not None else signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_SETMASK, held)
        signal.signal(signal.SIGALRM, old[signal.SIGALRM] or signal.SIG_DFL)


@contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGALRM back while the block runs; deliver them afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = {*_SIGNALS, signal.SIGALRM}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
