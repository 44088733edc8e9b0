"""What a host program controls in a call: cancelling it, hearing its progress, its time budget.

A library call (``refine.refine_path``, ``refine.solve``) runs inside :func:`controlled`, which
records the host's ``cancel`` (a :class:`threading.Event`, or any callable returning ``True`` once the
call should stop) and ``progress`` (a callable given a :class:`Progress`) for the current thread and
context only: two threads, each with its own call, never see each other's.

Each stage tells the host when it has finished (:func:`stage_done`, called by
:meth:`refine.stopwatch.Stopwatch.lap` and after each round's verification) and checks for a cancel
there; inside IPOPT the
solver's iteration callback (:mod:`refine.optimise.watch`) asks it once per iteration and stops the
solver. A cancelled call raises :class:`refine.errors.Cancelled`, never a verdict.

Ctrl-C is Python's ``KeyboardInterrupt`` as everywhere else; inside IPOPT, CasADi catches it and
IPOPT returns ``NonIpopt_Exception_Thrown``, which the solve turns back into ``KeyboardInterrupt``
(:func:`interrupted_status`). Nothing here touches a signal handler, timer or mask.

A call's ``time_limit_s`` is one deadline for the whole call (:func:`controlled`): every place that
checks for a cancel (the end of each stage, each solve -> verify round, each IPOPT iteration) also
checks the clock, and past the deadline raises :class:`OutOfTime` naming the stage that stopped;
IPOPT's iteration callback stops the solver there, and a pass's solver is built with the time then
left (:func:`budget_s`) as ``max_wall_time``. Inside a pass's refinement the limit ends
that pass as ``timeout`` (:func:`out_of_time`, :func:`note_timeout`) and the run is returned whole;
elsewhere the library call turns :class:`OutOfTime` into a result whose status is ``"timeout"``
(:mod:`refine.run.timeout`). Never a verdict.
"""

from __future__ import annotations

import contextvars
import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from refine.errors import Cancelled

INTERRUPTED_STATUSES = frozenset({"NonIpopt_Exception_Thrown"})
"""IPOPT's return status when an exception that is not IPOPT's own stopped it: with refine's compiled
functions, CasADi's ``KeyboardInterruptException`` (a Ctrl-C caught between evaluations); CasADi
turns other evaluation errors into IPOPT's evaluation-error handling, not into this status."""


@dataclass(frozen=True)
class Progress:
    """Where a call is, for a host's ``progress`` callback.

    Attributes:
        stage: the stage that has just finished (``"load"``, ``"cad"``, ``"demo"``, ``"fuse"``,
            ``"build"``, ``"verify"`` (one per round), ``"refine"``, ``"timing"``, ``"line_check"``,
            ``"arc_check"`` (with ``[output] circular_moves``),
            ``"motions"``: the stage names of
            ``result.json``'s ``timings_s``), or ``"solve"`` for each IPOPT iteration.
        round: the solve -> verify round of the current pass, from 1 (0 outside the rounds).
        iteration: IPOPT's iteration within the current solve (0 outside a solve).
        figures: stage-specific numbers, e.g. ``objective`` and ``constraint_violation`` in a solve.
    """

    stage: str
    round: int = 0
    iteration: int = 0
    figures: dict[str, float] = field(default_factory=dict)


@dataclass
class Control:
    """The current call's cancel and progress hooks, and where it is (:func:`controlled`)."""

    cancel: Callable[[], bool] | None = None
    progress: Callable[[Progress], Any] | None = None
    stage: str = ""
    round: int = 0
    cancelled_in_solver: bool = False
    deadline: float = math.inf
    time_limit_s: float | None = None
    timed_out_in_solver: bool = False
    timed_out: bool = False


class OutOfTime(Exception):
    """The current call's ``time_limit_s`` ran out; caught by the library call (status ``"timeout"``).

    Attributes:
        stage: the stage that noticed (``"load"``, ``"fuse"``, ``"solve"``, ...).
        time_limit_s: the call's budget [s].
    """

    def __init__(self, stage: str, time_limit_s: float | None) -> None:
        super().__init__(f"time limit of {time_limit_s:g} s reached during the {stage} stage")
        self.stage = stage
        self.time_limit_s = time_limit_s


_current: contextvars.ContextVar[Control | None] = contextvars.ContextVar("refine_control", default=None)


def _as_predicate(cancel: threading.Event | Callable[[], bool] | None) -> Callable[[], bool] | None:
    if cancel is None:
        return None
    if isinstance(cancel, threading.Event):
        return cancel.is_set
    if not callable(cancel):
        raise TypeError(
            f"cancel must be a threading.Event or a callable returning bool, not {type(cancel).__name__}"
        )
    return cancel


@contextmanager
def controlled(
    cancel: threading.Event | Callable[[], bool] | None = None,
    progress: Callable[[Progress], Any] | None = None,
    time_limit_s: float | None = None,
) -> Iterator[Control]:
    """Run the block as one host call with these hooks (see the module docstring).

    ``time_limit_s``: the call's wall-time budget [s] from now; None for none.

    Raises:
        TypeError: ``cancel`` is neither an event nor callable, or ``progress`` is not callable.
    """
    if progress is not None and not callable(progress):
        raise TypeError(
            f"progress must be a callable taking a refine.control.Progress, not {type(progress).__name__}"
        )
    control = Control(cancel=_as_predicate(cancel), progress=progress, time_limit_s=time_limit_s)
    if time_limit_s is not None:
        control.deadline = time.perf_counter() + float(time_limit_s)
    token = _current.set(control)
    try:
        yield control
    except SystemError as e:  # Ctrl-C that landed inside a compiled call (CasADi's SWIG layer)
        if ctrl_c_inside(e):
            raise KeyboardInterrupt from e
        raise
    finally:
        _current.reset(token)


def ctrl_c_inside(error: BaseException) -> bool:
    """Whether ``error`` is a ``SystemError`` a Ctrl-C caused inside a compiled call.

    A SIGINT whose Python handler runs while a compiled function (CasADi's SWIG wrappers, such as
    ``DM.__array__``) is returning makes CPython raise ``SystemError("... returned a result with an
    exception set")`` with the ``KeyboardInterrupt`` as its cause; a host must see the interrupt.
    """
    seen: BaseException | None = error
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def current() -> Control | None:
    """The current call's :class:`Control`, or None outside :func:`controlled`."""
    return _current.get()


def cancel_requested() -> bool:
    """Whether the current call's host has asked it to stop."""
    control = _current.get()
    return bool(control is not None and control.cancel is not None and control.cancel())


def remaining_s() -> float | None:
    """Seconds left of the current call's ``time_limit_s`` (0 once past it), or None without one."""
    control = _current.get()
    if control is None or control.time_limit_s is None:
        return None
    return max(0.0, control.deadline - time.perf_counter())


def budget_s(limit_s: float) -> float:
    """``limit_s`` [s], or the current call's time left when less (at least 1 ms: IPOPT wants > 0)."""
    left = remaining_s()
    return limit_s if left is None else max(1e-3, min(limit_s, left))


def check_cancelled(where: str) -> None:
    """Raise :class:`Cancelled` if the host asked the current call to stop, :class:`OutOfTime` past its limit.

    Args:
        where: the stage that noticed, for the message (e.g. ``"seed"``).
    """
    if cancel_requested():
        raise Cancelled(f"cancelled by the caller during the {where} stage")
    control = _current.get()
    if control is not None and not control.timed_out and time.perf_counter() >= control.deadline:
        raise OutOfTime(where, control.time_limit_s)


def out_of_time() -> bool:
    """Whether the current call is past its ``time_limit_s``."""
    control = _current.get()
    return control is not None and time.perf_counter() >= control.deadline


def stop_if_out_of_time(where: str) -> None:
    """Raise :class:`OutOfTime` past the current call's limit, even after a pass's ``timeout``.

    For a stage whose own runs (the placement repair's strict runs) may have noted a timeout that
    is not the call's verdict.
    """
    control = _current.get()
    if control is not None and time.perf_counter() >= control.deadline:
        raise OutOfTime(where, control.time_limit_s)


def note_timeout() -> float | None:
    """Note that a pass of the current call has the status ``timeout``; the call's limit [s] or None.

    From then on the call's stages finish without :class:`OutOfTime` (the run has its verdict-free
    status, and is returned whole), and no further pass is started (:func:`timed_out`).
    """
    control = _current.get()
    if control is None:
        return None
    control.timed_out = True
    return control.time_limit_s


def timed_out() -> bool:
    """Whether a pass of the current call has the status ``timeout`` (:func:`note_timeout`)."""
    control = _current.get()
    return control is not None and control.timed_out


def stage_done(name: str, **figures: float) -> None:
    """Tell the current call's host that stage ``name`` has finished; stop if it asked to.

    Raises:
        Cancelled: the host asked the call to stop.
    """
    control = _current.get()
    if control is None:
        return
    control.stage = name
    if control.progress is not None:
        control.progress(Progress(name, control.round, 0, dict(figures)))
    check_cancelled(name)


def enter_round(round: int) -> None:
    """Note that the current call's refinement starts solve -> verify round ``round`` (from 1)."""
    control = _current.get()
    if control is not None:
        control.round = round


def solver_iteration(iteration: int, **figures: float) -> bool:
    """From inside a solver: tell the host, and whether the solver should stop (cancelled)."""
    control = _current.get()
    if control is None:
        return False
    if control.progress is not None:
        control.progress(Progress("solve", control.round, iteration, dict(figures)))
    if control.cancel is not None and control.cancel():
        control.cancelled_in_solver = True
        return True
    if time.perf_counter() >= control.deadline:
        control.timed_out_in_solver = True
        return True
    return False


def after_solve(return_status: str, interrupted: bool = False) -> None:
    """Turn a solver stopped by the host or by Ctrl-C into :class:`Cancelled` or ``KeyboardInterrupt``.

    Called with IPOPT's return status right after each solve, before the status could become a
    verdict; ``interrupted``: a ``KeyboardInterrupt`` stopped the solver's iteration callback.
    A solve the callback stopped at the call's time limit returns: the refinement ends as ``timeout``.
    """
    control = _current.get()
    if control is not None and control.cancelled_in_solver:
        control.cancelled_in_solver = False
        raise Cancelled(f"cancelled by the caller inside the solver (IPOPT: {return_status})")
    if control is not None and control.timed_out_in_solver:
        control.timed_out_in_solver = False  # the refinement ends as timeout (its own deadline check)
        return
    if interrupted or return_status in INTERRUPTED_STATUSES:
        raise KeyboardInterrupt(f"interrupted inside the solver (IPOPT: {return_status})")
