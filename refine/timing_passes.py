"""TOPP-RA's two passes with toppra's solver only where no bound proves its answer.

toppra's ``TOPPRA.compute_parameterization`` runs a backward pass (the controllable sets, two
calls of the solver wrapper's ``solve_stagewise_optim`` per gridpoint, through ``_one_step``) and a
forward pass (one call per gridpoint, through ``_forward_step``), each call a small LP in the
stage's path acceleration ``u`` and squared speed ``x`` with its rows ``A u + B x + C <= 0``.
Making the instance asks importlib which of toppra's solver wrappers are installed, at each call.

:func:`lean_passes` makes a subclass of a toppra algorithm class whose passes make toppra's calls
with the same arguments (the cost vectors ``(1e-9, -1, 0, ...)`` and its negation backward,
``(-2 delta_i, -1, 0, ...)`` forward), the same clamping of a negative lower end to 0, the same
early stop at a NaN set, the same shaving of each next ``x`` (``max(x - TINY, 0.9999 x)``), the
same clamping into the next controllable set and the same retries (at most ``MAX_TRIES`` times
``x`` lowered by 0.1 %) where a step has no solution, except where the answer of a call is proved
without it:

* the lower end of a stage's set is 0 where rest meets every row and bound of the stage and the
  next set is ``[0, hi]`` (toppra's minimisation returns 0 to within its rounding, a few 1e-16
  [m^2/s^2]);
* the upper end is the stage's largest bounded ``x`` where, there, the rows leave an interval of
  ``u`` that also reaches the next set, wider than a margin of 1e-9 relative
  (:func:`stage_shortcuts`);
* the forward step's ``u`` is the one onto the next set's top where that ``u`` lies inside the
  rows' interval at ``x``, bounded from a guess of ``x`` by each row's slope
  (:func:`forward_certificates`).

Where the next set is the single point 0 (the stage before the end of a rest-to-rest timing),
the upper end is the largest ``x`` from which the rows let one step stop (:func:`top_to_rest`).
Runs of such stages are taken at once (:func:`forward_guess`: along the top, the step from
``g[i]`` gives ``g[i + 1]`` to the bit), so the result is the one a stage-by-stage loop of the same
rules gives. The seidel wrapper (toppra's own choice once asked for it) is made when a step first
needs it: on the glass cell's 618 gridpoints no step needs it (toppra's passes solve 1851 LPs),
the path speeds are toppra's own to 2e-16 and the cycle time to the bit
(``tests/test_timing_passes.py``, ``tests/test_timing.py``).
"""

from __future__ import annotations

import logging
from math import isnan
from typing import Any

import numpy as np

from refine.types import Array

_TOPPRA_LOG = logging.getLogger("toppra.algorithm.reachabilitybased.reachability_algorithm")
"""toppra's own logger of the passes (its warning on a set that cannot be computed)."""


_VAR_BOUND = 1e8
"""toppra's seidel wrapper bounds ``u`` and ``x`` to +-1e8 where no constraint bounds them."""
_TOP_MARGIN_REL = 1e-9
"""Relative margin [-] by which a proved answer must clear the rows: far above the rounding of the
interval's ends, which :func:`_row_ends` takes off them besides."""
_EPS = float(np.finfo(float).eps)


def _row_ends(A: Array, B: Array, C: Array, x: Array) -> tuple[Array, Array, Array]:
    """Each row's end ``u = -(B x + C) / A`` at ``x`` per stage, pulled in by its rounding.

    ``-(B x + C)`` is within ``2 eps (|B x| + |C|)`` of its value and the division adds
    ``eps |ratio|``: four times both, taken off the upper ends (``A > 0``) and added to the lower
    ends (``A < 0``), leave ends that the exact ones cannot be inside of.

    Returns:
        ``rest = -(B x + C)`` shape (N + 1, m), the upper and the lower end per row (+-inf on
        rows that do not bound ``u`` that way).
    """
    rest = -(B * x[:, None] + C)  # A u <= rest
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = rest / A
        slack = 8.0 * _EPS * ((np.abs(B * x[:, None]) + np.abs(C)) / np.abs(A) + np.abs(ratio))
        upper = np.where(A > 0.0, ratio - slack, np.inf)
        lower = np.where(A < 0.0, ratio + slack, -np.inf)
    return rest, upper, lower


def stage_rows(params: list, n_points: int) -> tuple[Array, Array, Array, Array]:
    """The stage LPs' rows ``A u + B x + C <= 0`` and the bounds on ``x``, from the constraint parameters.

    Args:
        params: the solver wrapper's constraint parameters, ``(a, b, c, F, h, ubound, xbound)`` per
            constraint as toppra's ``compute_constraint_params`` gives them (rows
            ``F (a u + b x + c) <= h``, ``ubound`` on ``u``, ``xbound`` on ``x``).
        n_points: number of gridpoints.

    Returns:
        ``A, B, C`` shape (n_points, m) (the two bounds on ``u`` among the rows; column-major),
        ``x_bounds`` shape (n_points, 2) [m^2/s^2], as the seidel wrapper makes them.
    """
    u_bounds = np.tile([-_VAR_BOUND, _VAR_BOUND], (n_points, 1))
    x_bounds = u_bounds.copy()
    blocks = []  # (F, h, a, b, c) of the constraints with rows
    for a, b, c, F, h, ubound, xbound in params:
        if a is not None:
            F, h = np.asarray(F), np.asarray(h)
            blocks.append((F, h, a, b, c))
        for bound, into in ((ubound, u_bounds), (xbound, x_bounds)):
            if bound is not None:
                into[:, 0] = np.maximum(into[:, 0], np.asarray(bound)[:, 0])
                into[:, 1] = np.minimum(into[:, 1], np.asarray(bound)[:, 1])
    m = sum(F.shape[-2] for F, *_ in blocks) + 2
    # column-major: each stage's row of A, B, C is strided, each row's column contiguous, so the
    # passes' reductions over a stage's rows run column by column over every stage at once
    A, B, C = (np.empty((n_points, m), order="F") for _ in range(3))
    B[:] = 0.0
    k = 0
    for F, h, a, b, c in blocks:  # each constraint's rows into its columns
        cols = slice(k, k + F.shape[-2])
        if F.ndim == 3:
            A[:, cols] = np.einsum("ikj,ij->ik", F, a)
            B[:, cols] = np.einsum("ikj,ij->ik", F, b)
            C[:, cols] = np.einsum("ikj,ij->ik", F, c) - h
        else:
            A[:, cols] = a @ F.T
            B[:, cols] = b @ F.T
            C[:, cols] = c @ F.T - h
        k = cols.stop
    A[:, k], A[:, k + 1] = -1.0, 1.0  # u >= lower bound, u <= upper bound (B there is 0)
    C[:, k], C[:, k + 1] = u_bounds[:, 0], -u_bounds[:, 1]
    return A, B, C, x_bounds


def stage_shortcuts(rows: tuple[Array, Array, Array, Array]) -> tuple[Array, Array, Array, Array]:
    """Per gridpoint, what lets the backward pass skip a stage's solves.

    * ``x_top`` [m^2/s^2], the largest ``x`` the stage's bounds allow, and ``[u_lo, u_hi]``
      [m/s^2], the interval of ``u`` the rows leave at ``x_top`` (``u_lo = inf`` where a row
      without ``u`` or the lower bound on ``x`` excludes ``x_top``). ``x <= x_top`` holds on the
      whole stage, so where some ``u`` in that interval also takes ``x_top + 2 delta u`` into the
      next stage's set, the controllable set ends at ``x_top`` exactly.
    * ``at_rest``: whether rest, ``(u, x) = (0, 0)``, meets every row and bound (exactly). Where
      it does and the next stage's set is ``[0, hi]`` with ``hi >= 0``, ``x = 0`` is feasible
      (with ``u = 0`` the next ``x`` is 0 too) and every feasible ``x`` is >= 0 or clamped to 0: the
      controllable set's lower end is 0, which toppra's minimisation finds to within its rounding.

    Args:
        rows: ``A, B, C, x_bounds`` of :func:`stage_rows`.

    Returns:
        ``x_top, u_lo, u_hi, at_rest``, each shape (N + 1,).
    """
    A, B, C, x_bounds = rows
    x_top = x_bounds[:, 1]
    rest, upper, lower = _row_ends(A, B, C, x_top)
    u_lo, u_hi = np.max(lower, axis=1), np.min(upper, axis=1)
    excluded = np.any((A == 0.0) & (rest < 0.0), axis=1) | (x_bounds[:, 0] > x_top)
    u_lo[excluded | ~np.isfinite(u_lo) | ~np.isfinite(u_hi)] = np.inf
    at_rest = np.all(C <= 0.0, axis=1) & (x_bounds[:, 0] <= 0.0) & (x_bounds[:, 1] >= 0.0)
    return x_top, u_lo, u_hi, at_rest


def forward_certificates(rows: tuple[Array, Array, Array, Array], x_guess: Array) -> tuple[Array, ...]:
    """Per stage, what proves that the forward step's best ``u`` is the one onto the next set's top.

    With ``x`` fixed, the forward step maximises ``u`` over the rows ``A u <= -(B x + C)``, the
    bounds on ``x`` and ``lo <= x + 2 delta u <= hi``. Where ``u_cap = (hi - x) / (2 delta)`` lies
    inside the rows' interval ``[u_lo(x), u_hi(x)]`` and ``x`` inside its bounds, ``u_cap`` is the
    maximum (``u_cap >= (lo - x) / (2 delta)`` as ``hi >= lo``). The interval's ends are evaluated
    at a guess ``x_guess`` of each stage's ``x``; each row's end moves by ``|B / A| |x - x_guess|``
    at another ``x``, so ``u_hi(x) >= u_hi_g - L_hi |x - x_guess|``, and likewise ``u_lo(x)``; a
    row without ``u`` keeps ``-(B x + C) >= slack_0 - L_0 |x - x_guess|``.

    Args:
        rows: ``A, B, C, x_bounds`` of :func:`stage_rows`, shape (N + 1, m) and (N + 1, 2).
        x_guess: the guess of ``x`` at each gridpoint [m^2/s^2], shape (N + 1,).

    Returns:
        ``u_hi_g, L_hi, u_lo_g, L_lo, slack_0, L_0``, each shape (N + 1,); ends are +-inf where
        no row bounds ``u`` that way (the seidel wrapper's +-1e8 bounds are rows).
    """
    u_hi, u_lo, slack_0 = guess_ends(rows, x_guess)
    L_hi, L_lo, L_0 = end_slopes(rows)
    return u_hi, L_hi, u_lo, L_lo, slack_0, L_0


def guess_ends(rows: tuple[Array, Array, Array, Array], x_guess: Array) -> tuple[Array, Array, Array]:
    """``u_hi_g, u_lo_g, slack_0`` of :func:`forward_certificates`: the rows' ends at the guess, each (N + 1,)."""
    A, B, C, _ = rows
    rest, upper, lower = _row_ends(A, B, C, x_guess)
    flat = A == 0.0
    slack_0 = np.min(np.where(flat, rest, np.inf), axis=1) if flat.any() else np.full(len(A), np.inf)
    return np.min(upper, axis=1), np.max(lower, axis=1), slack_0


def end_slopes(rows: tuple[Array, Array, Array, Array]) -> tuple[Array, Array, Array]:
    """``L_hi, L_lo, L_0`` of :func:`forward_certificates`: how fast the ends move with ``x``, each (N + 1,).

    Only a step whose ``x`` is off the guess needs them.
    """
    A, B, _, _ = rows
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        slope = np.abs(B / A)
    L_hi = np.max(np.where(A > 0.0, slope, 0.0), axis=1)
    L_lo = np.max(np.where(A < 0.0, slope, 0.0), axis=1)
    L_0 = np.max(np.where(A == 0.0, np.abs(B), 0.0), axis=1)
    return L_hi, L_lo, L_0


def _step_onto_top(x: Array, K: Array, two_deltas: Array, tiny: float) -> tuple[Array, Array]:
    """The forward step from ``x[i]`` with ``u = (K[i + 1, 1] - x[i]) / (2 delta_i)``: ``u`` and the next ``x``.

    The same operations as the forward loop's, element by element, so the same bits.
    """
    u = (K[1:, 1] - x[:-1]) / two_deltas
    x_next = x[:-1] + two_deltas * u
    x_next = np.maximum(x_next - tiny, 0.9999 * x_next)
    return u, np.minimum(K[1:, 1], np.maximum(K[1:, 0], x_next))


def forward_guess(x_start: float, K: Array, two_deltas: Array, tiny: float) -> tuple[Array, Array, Array]:
    """Where the forward pass runs along the top of the controllable sets: the guess of its ``x``.

    Starting from the next set's top, shaved as the forward loop shaves, the step onto the top
    (:func:`_step_onto_top`) is applied to the whole guess a few times, until it reproduces it.

    Args:
        x_start: ``x`` at the first gridpoint [m^2/s^2].
        K: the controllable sets, shape (N + 1, 2) [m^2/s^2].
        two_deltas: ``2 delta_i`` [m], shape (N,).
        tiny: toppra's shaving constant [m^2/s^2].

    Returns:
        ``g`` shape (N + 1,), ``u_g`` shape (N,) (the step's ``u`` from ``g[i]``) and ``follows``
        shape (N,): whether the step from ``g[i]`` gives ``g[i + 1]`` to the bit.
    """
    top = K[:, 1]
    g = np.minimum(top, np.maximum(K[:, 0], np.maximum(top - tiny, 0.9999 * top)))
    g[0] = x_start
    for _ in range(4):
        u_g, g_next = _step_onto_top(g, K, two_deltas, tiny)
        follows = g_next == g[1:]
        if follows.all():
            break
        g[1:] = g_next
    u_g, g_next = _step_onto_top(g, K, two_deltas, tiny)
    return g, u_g, g_next == g[1:]


def _top_reached(x_top, u_lo, u_hi, at_rest, lo: Array, hi: Array, two_deltas: Array) -> Array:
    """Per stage, whether the backward pass takes the stage's top given the next set ``[lo, hi]``.

    The backward loop's test element by element (the same operations, so the same answers):
    rest reaches rest, and ``u`` at the top keeps an interval wider than the margin.
    """
    x_top, u_lo, u_hi, at_rest = x_top[:-1], u_lo[:-1], u_hi[:-1], at_rest[:-1]
    u_from = np.maximum(u_lo, (lo - x_top) / two_deltas)
    u_to = np.minimum(u_hi, (hi - x_top) / two_deltas)
    wide = u_to - u_from > _TOP_MARGIN_REL * (np.abs(u_from) + np.abs(u_to) + 1.0)
    return at_rest & (lo == 0.0) & (hi >= 0.0) & wide


def top_to_rest(rows: tuple[Array, Array, Array, Array], i: int, two_delta: float) -> float | None:
    """The largest ``x`` at stage ``i`` from which one step stops (``x + 2 delta u = 0``), or None.

    With ``u = -x / (2 delta)`` the rows read ``p x <= r``, ``p = B - A / (2 delta)``, ``r = -C``;
    where rest meets the stage's rows (``r >= 0``) the largest ``x`` is the least ``r / p`` over
    ``p > 0`` and the stage's top. ``p`` is a difference: where it loses more than 4 digits on a
    row that could bind, None (toppra's solver decides).

    Args:
        rows: ``A, B, C, x_bounds`` of :func:`stage_rows`.
        i: the stage.
        two_delta: ``2 delta_i`` [m].

    Returns:
        ``x`` [m^2/s^2], or None.
    """
    A, B, C, x_bounds = (r[i] for r in rows)
    p, r = B - A / two_delta, -C
    if np.any(r < 0.0):
        return None
    up = p > 0.0
    ends = r[up] / p[up]
    x = min(float(x_bounds[1]), float(ends.min()) if ends.size else np.inf)
    lost = (np.abs(B[up]) + np.abs(A[up] / two_delta)) / p[up]
    if not np.isfinite(x) or x < x_bounds[0] or np.any((lost > 1e4) & (ends <= 2.0 * x)):
        return None
    return x


def _last_false(flags: Array) -> Array:
    """Per index ``i``, the last index ``k <= i`` where ``flags`` is False (-1 if none)."""
    where = np.where(flags, -1, np.arange(len(flags)))
    return np.maximum.accumulate(where)


def _next_false(flags: Array) -> Array:
    """Per index ``i``, the first index ``k >= i`` where ``flags`` is False (``len(flags)`` if none)."""
    n = len(flags)
    where = np.where(flags, n, np.arange(n))
    return np.minimum.accumulate(where[::-1])[::-1]


def _strictly_increasing_grid(path: Any, gridpoints: Any) -> bool:
    """Whether toppra's ``ParameterizationAlgorithm`` accepts ``gridpoints`` of ``path`` without a word.

    Given gridpoints that span the path's interval and strictly increase (its check, one
    comparison per stage); otherwise (None, another span, a NaN) its own ``__init__`` decides.
    """
    if gridpoints is None:
        return False
    g = np.asarray(gridpoints)
    if g.ndim != 1 or len(g) < 2 or g.dtype.kind != "f":
        return False
    start, end = path.path_interval[0], path.path_interval[1]
    return bool(start == g[0] and end == g[-1] and np.all(g[1:] > g[:-1]))


def lean_passes(base: type) -> type:
    """A subclass of toppra algorithm class ``base`` (``toppra.algorithm.TOPPRA``) with lean passes."""
    import toppra.constants
    import toppra.exceptions
    from toppra.algorithm.algorithm import (
        ParameterizationAlgorithm,
        ParameterizationData,
        ParameterizationReturnCode,
    )
    from toppra.constraint import ConstraintType
    from toppra.parametrizer import ParametrizeSpline
    from toppra.solverwrapper.cy_seidel_solverwrapper import seidelWrapper

    tiny, small, max_tries = toppra.constants.TINY, toppra.constants.SMALL, toppra.constants.MAX_TRIES
    linear = ConstraintType.CanonicalLinear

    class LeanPasses(base):  # type: ignore[misc, valid-type]
        __doc__ = f"{base.__name__} whose backward and forward passes skip toppra's per-step Python."

        def __init__(self, constraint_list, path, gridpoints=None, solver_wrapper=None, **kwargs):
            if solver_wrapper != "seidel" or any(c.get_constraint_type() != linear for c in constraint_list):
                super().__init__(constraint_list, path, gridpoints, solver_wrapper, **kwargs)
                return
            # toppra's own choice of wrapper, seidel, made when a step first needs it
            if kwargs or not _strictly_increasing_grid(path, gridpoints):
                ParameterizationAlgorithm.__init__(
                    self, constraint_list, path, gridpoints=gridpoints, **kwargs
                )
                return
            # ParameterizationAlgorithm.__init__'s state, its gridpoint check vectorised
            self.constraints, self.path = constraint_list, path
            self._problem_data = ParameterizationData()
            self.gridpoints = np.array(gridpoints)
            self._problem_data.gridpoints = np.array(gridpoints)
            self._N = len(gridpoints) - 1
            self.parametrizer = ParametrizeSpline

        @property
        def solver_wrapper(self):  # noqa: D102
            wrapper = self.__dict__.get("_wrapper")
            if wrapper is None:
                wrapper = self._wrapper = seidelWrapper(
                    self.constraints, self.path, self.gridpoints, solve_lp1d=True
                )
            return wrapper

        @solver_wrapper.setter
        def solver_wrapper(self, wrapper) -> None:
            self._wrapper = wrapper

        def _solve(self, *args):
            """The wrapper's ``solve_stagewise_optim``, the wrapper made first if it is not yet."""
            return self.solver_wrapper.solve_stagewise_optim(*args)

        def _made_wrapper(self):
            """The solver wrapper if it is made (then its setup and close are called), else None."""
            return self.__dict__.get("_wrapper")

        def _two_deltas(self) -> Array:
            """``2 delta_i`` [m] per stage, as the wrappers make ``delta_i``, shape (N,)."""
            return 2 * (self.gridpoints[1:] - self.gridpoints[:-1])

        def _n_vars(self) -> int:
            """The stage LP's variables: ``u``, ``x`` (and no more with the seidel wrapper, made or not)."""
            wrapper = self._made_wrapper()
            return 2 if wrapper is None else wrapper.get_no_vars()

        def compute_parameterization(self, sd_start: float, sd_end: float, return_data: bool = False):  # noqa: D102
            if sd_end < 0 or sd_start < 0:
                raise toppra.exceptions.BadInputVelocities(
                    f"Negative path velocities: path velocities must be positive: ({sd_start}, {sd_end})"
                )
            data = self._problem_data
            failed = (None, None, None)
            K = self.compute_controllable_sets(sd_end, sd_end)
            if np.isnan(K).any():
                _TOPPRA_LOG.warning(
                    "An error occurred when computing controllable velocities. "
                    "The path is not controllable, or is badly conditioned."
                )
                data.return_code = ParameterizationReturnCode.FailUncontrollable
                return (*failed, K) if return_data else failed
            data.K = K
            x_start = sd_start**2
            if x_start + small < K[0, 0] or K[0, 1] + small < x_start:
                _TOPPRA_LOG.warning(
                    "The initial velocity is not controllable. %f not in (%f, %f)", x_start, K[0, 0], K[0, 1]
                )
                data.return_code = ParameterizationReturnCode.FailUncontrollable
                return (*failed, K) if return_data else failed
            xs, us, v_vec = self._forward_pass(x_start, K)
            sd_vec = np.sqrt(xs)
            sdd_vec = np.copy(us)
            data.sd_vec, data.sdd_vec = sd_vec, sdd_vec
            ok = not np.isnan(sd_vec).any()
            data.return_code = ParameterizationReturnCode.Ok if ok else ParameterizationReturnCode.ErrUnknown
            return (sdd_vec, sd_vec, v_vec, K) if return_data else (sdd_vec, sd_vec, v_vec)

        def _forward_pass(self, x_start: float, K: Array) -> tuple[Array, Array, Array]:
            """The forward loop of toppra: ``x`` [m^2/s^2] at each gridpoint, ``u`` [m/s^2], the auxiliaries.

            Each step is toppra's solve, or its answer ``u_cap`` where :func:`forward_certificates`
            proves it; runs of such steps are taken at once where ``x`` follows the guess ``g``
            exactly (the step from ``g[i]`` gives ``g[i + 1]`` to the bit).
            """
            wrapper = self._made_wrapper()
            N = self._N
            two_deltas_arr = self._two_deltas()
            xs, us = np.zeros(N + 1), np.zeros(N)
            v_vec = np.zeros((N, self._n_vars() - 2))
            nan = np.nan
            if wrapper is not None:
                wrapper.setup_solver()
            x, i, tries = float(x_start), 0, 0
            xs[0] = x
            solve, costs = self._solve, self._stage_costs()
            rows = self._stage_rows()
            g, u_g, good = forward_guess(x, K, two_deltas_arr, tiny)
            u_hi, u_lo, slack_0 = guess_ends(rows, g)  # the slopes only where a step leaves the guess
            x_bounds = rows[3]
            margin = _TOP_MARGIN_REL
            good &= (
                (x_bounds[:-1, 0] <= g[:-1])
                & (g[:-1] <= x_bounds[:-1, 1])
                & (u_g <= u_hi[:-1] - margin * (np.abs(u_hi[:-1]) + 1.0))
                & (u_g >= u_lo[:-1] + margin * (np.abs(u_lo[:-1]) + 1.0))
                & (slack_0[:-1] >= 0.0)
            )
            run_end = _next_false(good)
            if good[0] and x == g[0] and run_end[0] == N:  # one run of proved steps from start to end
                xs[1:] = g[1:]
                us[:] = u_g
                i = N
            else:
                run_end = run_end.tolist()
                good_list, g_list = good.tolist(), g.tolist()
                L_hi, L_lo, L_0 = end_slopes(rows)
                u_hi, L_hi, u_lo, L_lo, slack_0, L_0 = (
                    v.tolist() for v in (u_hi, L_hi, u_lo, L_lo, slack_0, L_0)
                )
                x_lo, x_hi = x_bounds[:, 0].tolist(), x_bounds[:, 1].tolist()
                K_lo, K_hi = K[:, 0].tolist(), K[:, 1].tolist()
                two_deltas = two_deltas_arr.tolist()
            while i < N:  # _forward_step's solve, inline, or its answer where it is proved
                if good_list[i] and x == g_list[i]:  # a run of proved steps along the guess
                    k = run_end[i]
                    xs[i + 1 : k + 1] = g[i + 1 : k + 1]
                    us[i:k] = u_g[i:k]
                    x, i, tries = g_list[k], k, 0
                    continue
                hi = K_hi[i + 1]
                u_cap = (hi - x) / two_deltas[i]
                d = abs(x - g_list[i])
                if (
                    x_lo[i] <= x <= x_hi[i]
                    and u_cap <= u_hi[i] - L_hi[i] * d - margin * (abs(u_hi[i]) + 1.0)
                    and u_cap >= u_lo[i] + L_lo[i] * d + margin * (abs(u_lo[i]) + 1.0)
                    and slack_0[i] >= L_0[i] * d
                ):
                    optim_res = (u_cap, x)
                elif isnan(x):
                    optim_res = (nan, nan)
                else:
                    optim_res = solve(i, None, costs[i], x, x, K_lo[i + 1], hi)
                if isnan(optim_res[0]):  # as toppra: lower x by 0.1 % and try again, a few times
                    if tries < max_tries:
                        x = max(x - tiny, 0.999 * x)
                        xs[i] = x
                        tries += 1
                        _TOPPRA_LOG.warning("forward pass failed at step %d: x lowered to %.6f", i, x)
                    else:
                        _TOPPRA_LOG.warning("the forward pass failed %d times at step %d", max_tries, i)
                        xs[i + 1 :] = nan
                        break
                else:
                    tries = 0
                    u = us[i] = optim_res[0]
                    x_next = x + two_deltas[i] * u
                    x_next = max(x_next - tiny, 0.9999 * x_next)
                    x = min(K_hi[i + 1], max(K_lo[i + 1], x_next))
                    xs[i + 1] = x
                    if len(optim_res) > 2:
                        v_vec[i] = optim_res[2:]
                    i += 1
            if self._made_wrapper() is not None:
                self._made_wrapper().close_solver()
            return xs, us, v_vec

        def compute_controllable_sets(self, sdmin: float, sdmax: float) -> Array:  # noqa: D102
            assert sdmin <= sdmax and 0 <= sdmin  # as toppra's
            N = self._N
            K_lo, K_hi = [0.0] * (N + 1), [0.0] * (N + 1)
            K_lo[N], K_hi[N] = sdmin**2, sdmax**2
            wrapper = self._made_wrapper()
            if wrapper is not None:
                wrapper.setup_solver()
            upper = np.zeros(self._n_vars())
            upper[0], upper[1] = 1e-9, -1
            lower = -upper
            solve = self._solve
            nan = np.nan
            rows = self._stage_rows()
            shortcuts = stage_shortcuts(rows)
            two_deltas_arr = self._two_deltas()
            # runs of stages that take their top, each from the next one's top (from K[N] at the end)
            lo_run, hi_run = np.zeros(N), shortcuts[0][1:].copy()
            lo_run[-1], hi_run[-1] = K_lo[N], K_hi[N]
            on_top = _top_reached(*shortcuts, lo_run, hi_run, two_deltas_arr)
            run_start = _last_false(on_top)
            if on_top[N - 1] and run_start[N - 1] == -1:  # one run: every stage takes its top
                if self._made_wrapper() is not None:
                    self._made_wrapper().close_solver()
                K = np.zeros((N + 1, 2))
                K[:N, 1] = shortcuts[0][:N]
                K[N] = K_lo[N], K_hi[N]
                return K
            run_start = run_start.tolist()
            lo_run, hi_run, on_top = lo_run.tolist(), hi_run.tolist(), on_top.tolist()
            x_top, u_lo, u_hi, at_rest = (v.tolist() for v in shortcuts)
            two_deltas = two_deltas_arr.tolist()
            i = N - 1
            while i >= 0:
                lo, hi = K_lo[i + 1], K_hi[i + 1]
                if on_top[i] and lo == lo_run[i] and hi == hi_run[i]:
                    k = run_start[i]
                    K_hi[k + 1 : i + 1] = x_top[k + 1 : i + 1]  # K_lo there stays 0
                    i = k
                    continue
                if isnan(lo) or isnan(hi):
                    K_lo[i] = K_hi[i] = nan
                elif at_rest[i] and lo == 0.0 and hi >= 0.0:  # rest reaches rest: the lower end is 0
                    top = x_top[i]
                    u_from = max(u_lo[i], (lo - top) / two_deltas[i])
                    u_to = min(u_hi[i], (hi - top) / two_deltas[i])
                    if u_to - u_from > _TOP_MARGIN_REL * (abs(u_from) + abs(u_to) + 1.0):
                        K_hi[i] = top  # the stage's top reaches the next set: nothing is higher
                    elif hi == 0.0 and (stop := top_to_rest(rows, i, two_deltas[i])) is not None:
                        K_hi[i] = stop
                    else:
                        K_hi[i] = solve(i, None, upper, nan, nan, lo, hi)[1]
                else:
                    x_upper = solve(i, None, upper, nan, nan, lo, hi)[1]
                    x_lower = solve(i, None, lower, nan, nan, lo, hi)[1]
                    K_lo[i], K_hi[i] = (0 if x_lower < 0 else x_lower), x_upper
                if isnan(K_lo[i]) or isnan(K_hi[i]):
                    _TOPPRA_LOG.warning(
                        "A numerical error occurs: The controllable set at step [%d / %d] can't be computed.",
                        i,
                        N + 1,
                    )
                    return np.column_stack([K_lo, K_hi])
                i -= 1
            if self._made_wrapper() is not None:
                self._made_wrapper().close_solver()
            return np.column_stack([K_lo, K_hi])

        def _stage_rows(self) -> tuple[Array, Array, Array, Array]:
            """The wrapper's rows and bounds on ``x`` (:func:`stage_rows`), made once per instance."""
            rows = self.__dict__.get("_rows")
            if rows is None:
                wrapper = self._made_wrapper()
                if wrapper is not None:
                    params = wrapper.params
                else:  # what the seidel wrapper computes when it is made
                    params = [
                        c.compute_constraint_params(self.path, self.gridpoints) for c in self.constraints
                    ]
                rows = self._rows = stage_rows(params, self._N + 1)
            return rows

        def _stage_costs(self) -> Array:
            """Per stage the forward step's cost ``(-2 delta_i, -1, 0, ...)``, as toppra makes it each step."""
            costs = self.__dict__.get("_forward_costs")
            if costs is None:
                costs = np.zeros((self._N, self._n_vars()))
                costs[:, 1] = -1
                costs[:, 0] = -self._two_deltas()
                self._forward_costs = costs
            return costs

        def _forward_step(self, i: int, x: Any, K_next: Array) -> Array:
            if i < 0 or i > self._N or x is None or isnan(x):
                return np.array([np.nan, np.nan])
            costs = self._stage_costs()
            return self.solver_wrapper.solve_stagewise_optim(i, None, costs[i], x, x, K_next[0], K_next[1])

    LeanPasses.__name__ = LeanPasses.__qualname__ = f"Lean{base.__name__}"
    return LeanPasses
