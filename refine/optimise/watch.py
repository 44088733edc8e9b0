"""IPOPT's iteration callback: the host's progress and cancel hooks (:mod:`refine.control`) per iteration.

:func:`iteration_watch` builds a CasADi ``Callback`` with the solver's output signature, given to
``nlpsol`` as ``iteration_callback``. Once per IPOPT iteration it reports the iteration and objective
to the current call's ``progress`` and returns 1 (stop) when the call's
``cancel`` says so; IPOPT then ends with ``User_Requested_Stop`` and
:func:`refine.control.after_solve` raises :class:`refine.errors.Cancelled`. Outside a controlled
call it reports nothing. It also stops IPOPT (returns 1) once the clock passes its ``deadline``
(the refinement's own time limit, set before each solve by :class:`refine.optimise.rounds.RoundLoop`;
inf for none), so a solve that starts with little of the limit left ends within an iteration of it
whatever its ``max_wall_time``; the round loop then ends the refinement as ``timeout``. A
``KeyboardInterrupt`` that lands in its Python code (Ctrl-C while it runs) stops IPOPT the same way
and is raised again once IPOPT has returned.
"""

from __future__ import annotations

import math
import time

import casadi as ca

from refine.control import solver_iteration

_OUTPUTS = ("x", "f", "g", "lam_x", "lam_g", "lam_p")


class IterationWatch(ca.Callback):
    """The callback object; keep a reference as long as the solver lives (CasADi does not)."""

    def __init__(self, nx: int, ng: int, np_: int) -> None:
        ca.Callback.__init__(self)
        self.sizes = {"x": nx, "f": 1, "g": ng, "lam_x": nx, "lam_g": ng, "lam_p": np_}
        self.iteration = 0
        self.interrupted = False
        self.deadline = math.inf  # time.perf_counter() [s] past which the solve stops
        self.construct("refine_iteration_watch", {})

    def get_n_in(self) -> int:  # noqa: D102 - CasADi's Callback protocol
        return len(_OUTPUTS)

    def get_n_out(self) -> int:  # noqa: D102
        return 1

    def get_name_in(self, i: int) -> str:  # noqa: D102
        return _OUTPUTS[i]

    def get_name_out(self, i: int) -> str:  # noqa: D102
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:  # noqa: D102
        return ca.Sparsity.dense(self.sizes[_OUTPUTS[i]], 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:  # noqa: D102
        return ca.Sparsity.dense(1, 1)

    def eval(self, arg: list) -> list:  # noqa: D102
        self.iteration += 1
        try:
            stop = solver_iteration(self.iteration, objective=float(arg[1]))
        except KeyboardInterrupt:  # Ctrl-C landed in this Python code: stop IPOPT, re-raised after it
            self.interrupted = True
            return [1]
        return [1 if stop or time.perf_counter() >= self.deadline else 0]


def iteration_watch(nx: int, ng: int, np_: int) -> IterationWatch:
    """A new :class:`IterationWatch` for a solver with ``nx`` variables, ``ng`` rows, ``np_`` parameters."""
    return IterationWatch(nx, ng, np_)
