"""TOPP-RA's two passes without toppra's per-step Python: the same solver calls, fewer allocations.

toppra's ``TOPPRA.compute_parameterization`` runs a backward pass (the controllable sets, two
calls of the solver wrapper's ``solve_stagewise_optim`` per gridpoint, through ``_one_step``) and a
forward pass (one call per gridpoint, through ``_forward_step``). Each step allocates the cost
vector again, checks its inputs through NumPy and formats nothing but still asks the logger, which
on the glass cell's 618 gridpoints is about half of the call's time.

:func:`lean_passes` makes a subclass of a toppra algorithm class whose two passes make the same
calls of ``solve_stagewise_optim`` with the same arguments in the same order: the cost vectors
``(1e-9, -1, 0, ...)`` and its negation (backward), ``(-2 delta_i, -1, 0, ...)`` (forward, one row
of an array made once per instance), the same bounds, the same clamping of a negative lower end to
0 and the same early stop at a NaN set. The timing is toppra's to the bit
(``tests/test_timing.py``). The rest of ``compute_parameterization`` (the start speed's check,
the forward loop with its retries) is toppra's own.
"""

from __future__ import annotations

import logging
from math import isnan
from typing import Any

import numpy as np

from refine.types import Array

_TOPPRA_LOG = logging.getLogger("toppra.algorithm.reachabilitybased.reachability_algorithm")
"""toppra's own logger of the passes (its warning on a set that cannot be computed)."""


def lean_passes(base: type) -> type:
    """A subclass of toppra algorithm class ``base`` (``toppra.algorithm.TOPPRA``) with lean passes."""

    class LeanPasses(base):  # type: ignore[misc, valid-type]
        __doc__ = f"{base.__name__} whose backward and forward passes skip toppra's per-step Python."

        def compute_controllable_sets(self, sdmin: float, sdmax: float) -> Array:  # noqa: D102
            assert sdmin <= sdmax and 0 <= sdmin  # as toppra's
            N = self._N
            K = np.zeros((N + 1, 2))
            K[N] = [sdmin**2, sdmax**2]
            wrapper = self.solver_wrapper
            wrapper.setup_solver()
            upper = np.zeros(wrapper.get_no_vars())
            upper[0], upper[1] = 1e-9, -1
            lower = -upper
            solve = wrapper.solve_stagewise_optim
            nan = np.nan
            for i in range(N - 1, -1, -1):
                lo, hi = K[i + 1, 0], K[i + 1, 1]
                if isnan(lo) or isnan(hi):
                    K[i] = nan
                else:
                    x_upper = solve(i, None, upper, nan, nan, lo, hi)[1]
                    K[i, 0], K[i, 1] = solve(i, None, lower, nan, nan, lo, hi)[1], x_upper
                    if K[i, 0] < 0:
                        K[i, 0] = 0
                if isnan(K[i, 0]) or isnan(K[i, 1]):
                    _TOPPRA_LOG.warning(
                        "A numerical error occurs: The controllable set at step [%d / %d] can't be computed.",
                        i,
                        N + 1,
                    )
                    return K
            wrapper.close_solver()
            return K

        def _forward_step(self, i: int, x: Any, K_next: Array) -> Array:
            if i < 0 or i > self._N or x is None or isnan(x):
                return np.array([np.nan, np.nan])
            costs = self.__dict__.get("_forward_costs")
            if costs is None:  # per stage: (-2 delta_i, -1, 0, ...), as toppra makes it each step
                wrapper = self.solver_wrapper
                costs = np.zeros((wrapper.get_no_stages(), wrapper.get_no_vars()))
                costs[:, 1] = -1
                costs[:, 0] = -2 * np.asarray(wrapper.get_deltas())
                self._forward_costs = costs
            return self.solver_wrapper.solve_stagewise_optim(i, None, costs[i], x, x, K_next[0], K_next[1])

    LeanPasses.__name__ = LeanPasses.__qualname__ = f"Lean{base.__name__}"
    return LeanPasses
