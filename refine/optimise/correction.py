"""A re-solve as a Newton correction of the previous answer's KKT system, verified or refused.

After a small change (the part moved a few millimetres, another cone) the answer of the kept
problem (:mod:`refine.optimise.warm`) is near the previous one and, as a rule, its active set is the
same: the cone rows, clearance rows, singularity bounds, joint-step rows and joint limits that
bound the previous answer bound the new one, and no other. The KKT conditions of the problem with
that active set held as equalities and the other inequalities dropped,

    ∇f(x) + J_A(x)ᵀ λ_A = 0,    g_A(x) = b_A,

are then a square nonlinear system, which Newton's method solves from the moved previous answer in
a few steps to machine precision (:func:`newton_correction`): no barrier, no line search, no
CasADi/IPOPT/MUMPS set-up. The problem is banded (each waypoint's joints couple only to the next
two through the joint-step and smoothness terms, every row touches one waypoint or two neighbours):
a step is a QR factorisation of each waypoint's held rows and a banded Cholesky factorisation of
the reduced Hessian, or a banded LU factorisation of the whole KKT matrix where a held row spans
two waypoints (:mod:`refine.optimise.kkt`), in time linear in the waypoints.

The answer is accepted only when it is the IPOPT problem's answer too (:func:`accept`): every
constraint (the dropped rows, the variable bounds) holds within IPOPT's constraint tolerance, every
active inequality's multiplier has the sign of a bound that pushes back, and the KKT residual is
under IPOPT's tolerance. Anything else (a row that became active, one that let go, no
convergence, a singular matrix, a reduced Hessian that is not positive definite) refuses the correction with the reason, and the caller solves with
IPOPT as before (:class:`refine.optimise.rounds.RoundLoop`). An accepted answer still runs through
the verification of any other answer.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from refine.optimise.kkt import NotLocal, evaluator_for, null_space_step, solve_banded_kkt
from refine.optimise.problem import RefinementNLP
from refine.types import Array

log = logging.getLogger(__name__)


ACTIVE_MULTIPLIER = 1e-6
"""A previous inequality row (or variable bound) is taken as active when its multiplier is larger
than this, at the side its sign names. An interior-point answer has λ·s = μ (about 1e-11 at IPOPT's
tolerance): a row that binds has a multiplier of 1e-5 or more (the cost is in squared degrees), one
clear of its bound by 1e-4 a multiplier of 1e-7 or less. A row in between (within about √μ of
its bound) guessed on the wrong side is caught by :func:`accept`, and the correction refused."""


MAX_NEWTON_STEPS = 8
"""Newton steps at most. The correction has converged when the KKT residual is under IPOPT's
tolerance and the held rows are met within its constraint tolerance, after one step at least; with
the exact Hessian two steps do (from 2.6e-5 rad off: 1e-10, then 1e-15)."""


CHORD_STEP_RAD = 1e-3
"""A Newton step after one that moved no joint by more than this [rad] keeps the last step's
factorisation (a chord step: the Jacobian's change goes into the right-hand side). The matrices
have then changed by about that fraction of themselves, and a chord step shrinks the error by about
that factor where a Newton step squares it: on the glass cell the first step moves 2.6e-5 rad and
leaves 1e-10 rad, the chord step after it 1e-15, without the Hessian's evaluation and the
factorisations."""


@dataclass(frozen=True)
class Correction:
    """A verified Newton correction.

    Attributes:
        x: the answer, the problem's variables (N·n) [rad].
        lam_g: the multipliers of every constraint row (CasADi's sign: > 0 at an upper bound,
            < 0 at a lower bound, zero for an inactive row).
        lam_x: the multipliers of the variable bounds (the same sign convention).
        iterations: Newton steps taken.
        stationarity: the largest entry of ∇f + Jᵀλ_g + λ_x at ``x`` [cost units per rad].
        violation: the largest constraint or bound violation at ``x`` (row units: m, cosine, rad).
    """

    x: Array
    lam_g: Array
    lam_x: Array
    iterations: int
    stationarity: float
    violation: float


@dataclass(frozen=True)
class ActiveRows:
    """The active set the correction holds: rows and bounds as equalities, at which side.

    Attributes:
        rows: indices of the constraint rows held (equalities and active inequalities).
        side: per held row, -1 at its lower bound, +1 at its upper bound, 0 an equality row.
        bounds: indices of the variables held at a bound.
        bound_side: per held variable, -1 at its lower bound, +1 at its upper bound.
    """

    rows: Array
    side: Array
    bounds: Array
    bound_side: Array


def _tolerances(problem: RefinementNLP) -> tuple[float, float]:
    """IPOPT's KKT tolerance and constraint tolerance for ``problem``."""
    options = problem.solver_options
    return float(options.get("ipopt.tol", 1e-8)), float(options.get("ipopt.constr_viol_tol", 1e-4))


def active_rows(
    lbg: Array, ubg: Array, lam_g: Array, lbx: Array, ubx: Array, lam_x: Array, no_upper: Array | None = None
) -> ActiveRows:
    """The active set that the multipliers ``lam_g`` of rows and ``lam_x`` of the variables name.

    Equality rows are always held; an inequality row or a bound is held at the side its
    multiplier's sign names when the multiplier is larger than :data:`ACTIVE_MULTIPLIER`.
    ``no_upper`` (rows,) marks the rows whose upper bound is never held: the cone rows, whose
    upper bound 1 + 1e-9 is the largest cosine there is. A waypoint on the demonstrated orientation
    sits on it with a multiplier of IPOPT's making, but the row's gradient vanishes there (the
    cosine is at its maximum), so holding it would leave the KKT matrix singular.
    """
    side_g = np.where(lam_g > ACTIVE_MULTIPLIER, 1, 0) - np.where(lam_g < -ACTIVE_MULTIPLIER, 1, 0)
    if no_upper is not None:
        side_g[no_upper & (side_g > 0)] = 0
    side_g = np.where(np.isfinite(np.where(side_g > 0, ubg, lbg)), side_g, 0)
    equal = lbg == ubg
    side_g[equal] = 0
    rows = np.flatnonzero(equal | (side_g != 0))
    side_x = np.where(lam_x > ACTIVE_MULTIPLIER, 1, 0) - np.where(lam_x < -ACTIVE_MULTIPLIER, 1, 0)
    side_x = np.where(np.isfinite(np.where(side_x > 0, ubx, lbx)), side_x, 0)
    bounds = np.flatnonzero(side_x != 0)
    return ActiveRows(rows, side_g[rows], bounds, side_x[bounds])


def correct(
    problem: RefinementNLP, x0: Array, lam_g0: Array, lam_x0: Array
) -> tuple[Correction | None, str]:
    """The answer of ``problem`` near ``x0`` by Newton's method on its KKT system, or None and why not.

    ``lam_g0``, ``lam_x0``: the previous answer's multipliers of every row and variable bound
    (CasADi's sign convention), which name the active set (:func:`active_rows`). The answer is
    returned only when :func:`accept` finds it an answer of the whole problem with that active set.
    """
    if problem.elastic_deg is not None or not problem.derivatives:
        return None, "the problem has no assembled derivatives or is elastic"
    lam_g0, lam_x0 = np.asarray(lam_g0, dtype=float), np.asarray(lam_x0, dtype=float)
    if lam_g0.shape != problem.lbg.shape or lam_x0.shape != problem.lbx.shape:
        return None, "the multipliers do not fit the problem's rows and variables"
    cone = np.zeros(len(problem.lbg), dtype=bool)
    cone[3 : 4 * problem.n_waypoints : 4] = True
    active = active_rows(problem.lbg, problem.ubg, lam_g0, problem.lbx, problem.ubx, lam_x0, cone)
    return newton_correction(problem, np.asarray(x0, dtype=float), active, lam_g0, lam_x0)


def newton_correction(
    problem: RefinementNLP, x0: Array, active: ActiveRows, lam_g0: Array, lam_x0: Array
) -> tuple[Correction | None, str]:
    """Newton's method on the KKT system of ``problem`` with ``active`` held, from ``x0``.

    ``lam_g0``, ``lam_x0``: the start multipliers (of every row and bound; only the held ones
    count). Returns the verified correction (:func:`accept`) and an empty reason, or None and why
    it was refused.
    """
    N, n = problem.n_waypoints, problem.dof
    nx = len(problem.lbx)
    x = np.asarray(x0, dtype=float).copy()
    rows, bounds = active.rows, active.bounds
    target = np.where(active.side > 0, problem.ubg[rows], problem.lbg[rows])
    x[bounds] = np.where(active.bound_side > 0, problem.ubx[bounds], problem.lbx[bounds])
    lam_g = np.zeros(len(problem.lbg))
    lam_g[rows] = lam_g0[rows]
    lam_x = np.zeros(nx)
    lam_x[bounds] = lam_x0[bounds]
    tol, ctol = _tolerances(problem)
    ev = evaluator_for(problem)
    try:
        nullspace = null_space_step(ev, rows, bounds, N, n)
    except NotLocal as e:
        log.debug("Newton correction: %s; the whole KKT matrix is factorised", e)
        nullspace = None
    step, factored, factors = np.inf, None, ()
    for iteration in range(MAX_NEWTON_STEPS + 1):
        # the first step always needs the Hessian: evaluated with the rows, at once
        grad, g, jac_values = ev.first_order(x, lam_g if iteration == 0 else None)
        stationarity = grad + ev.jacobian_t_times(jac_values, lam_g) + lam_x
        residual = target - g[rows]
        if iteration and np.abs(stationarity).max() <= tol and np.abs(residual).max(initial=0.0) <= ctol:
            return accept(problem, x, g, lam_g, lam_x, active, stationarity, iteration)
        if iteration == MAX_NEWTON_STEPS:
            break
        try:
            if nullspace is not None and step <= CHORD_STEP_RAD:
                # the last factorisation, the gradient corrected for the Jacobian's change
                dx, lam = nullspace.solve(factors, grad + ev.jacobian_t_times(jac_values - factored, lam_g), residual)
            elif nullspace is not None:
                factored = jac_values.copy()
                dx, lam, factors = nullspace.step(grad, jac_values, ev.hessian(lam_g), residual)
            else:
                hess_values = ev.hessian(lam_g)
                fix = sp.csr_matrix((np.ones(len(bounds)), (np.arange(len(bounds)), bounds)), shape=(len(bounds), nx))
                held = sp.vstack([ev.jacobian(jac_values)[rows], fix], format="csr")
                rhs = np.concatenate([-grad, residual, np.zeros(len(bounds))])
                z = solve_banded_kkt(ev.hessian_matrix(hess_values), held, rhs, n)
                dx, lam = z[:nx], z[nx:]
        except (np.linalg.LinAlgError, ValueError) as e:
            return None, f"Newton step {iteration + 1}: {e}"
        if not (np.all(np.isfinite(dx)) and np.all(np.isfinite(lam))):
            return None, f"Newton step {iteration + 1}: the KKT matrix is singular"
        step = float(np.abs(dx).max())
        x = x + dx
        lam_g[rows] = lam[: len(rows)]
        lam_x[bounds] = lam[len(rows) :]
    return None, (
        f"no convergence in {MAX_NEWTON_STEPS} Newton steps (last step {step:.1e} rad, "
        f"stationarity {np.abs(stationarity).max():.1e})"
    )


def accept(
    problem: RefinementNLP,
    x: Array,
    g: Array,
    lam_g: Array,
    lam_x: Array,
    active: ActiveRows,
    stationarity: Array,
    iterations: int,
) -> tuple[Correction | None, str]:
    """The correction at ``x`` (rows ``g``) if it is an answer of the whole problem, else None and why.

    Every row and variable bound within IPOPT's constraint tolerance (``ipopt.constr_viol_tol``),
    the multiplier of each active inequality row and bound of the sign of its side (or zero), and
    the KKT residual ``stationarity`` under IPOPT's tolerance (``ipopt.tol``). A row the answer
    breaks should have been held, a held one with a multiplier of the wrong sign let go: either
    way the active set changed.
    """
    tol, ctol = _tolerances(problem)
    stat = float(np.abs(stationarity).max())
    if stat > tol:
        return None, f"KKT residual {stat:.1e} over the tolerance {tol:.0e}"
    broken = np.maximum(problem.lbg - g, g - problem.ubg)
    r = int(np.argmax(broken)) if len(broken) else 0
    if len(broken) and broken[r] > ctol:
        side = "below its lower" if problem.lbg[r] - g[r] >= g[r] - problem.ubg[r] else "above its upper"
        return None, f"row {row_names(problem)[r]} {side} bound by {broken[r]:.1e}: the active set changed"
    beyond = np.maximum(problem.lbx - x, x - problem.ubx)
    j = int(np.argmax(beyond))
    if beyond[j] > ctol:
        return None, f"joint variable {j} beyond its limit by {beyond[j]:.1e} rad: the active set changed"
    pushing = np.where(active.side > 0, lam_g[active.rows], -lam_g[active.rows])
    wrong = np.flatnonzero((active.side != 0) & (pushing < -tol))
    if wrong.size:
        r = int(active.rows[wrong[0]])
        return None, (
            f"row {row_names(problem)[r]}: multiplier {lam_g[r]:.1e} of the wrong sign for its "
            f"{'upper' if active.side[wrong[0]] > 0 else 'lower'} bound ({wrong.size} rows): the active set changed"
        )
    pushing_x = np.where(active.bound_side > 0, lam_x[active.bounds], -lam_x[active.bounds])
    wrong = np.flatnonzero(pushing_x < -tol)
    if wrong.size:
        j = int(active.bounds[wrong[0]])
        return None, f"joint variable {j}: bound multiplier {lam_x[j]:.1e} of the wrong sign: the active set changed"
    violation = float(max(0.0, broken.max(initial=0.0), beyond.max()))
    return Correction(x, lam_g, lam_x, iterations, stat, violation), ""


def row_names(problem: RefinementNLP) -> list[tuple]:
    """A name for every constraint row of ``problem`` (as the rounds' multipliers are keyed)."""
    return names_of(row_layout(problem))


def row_layout(problem: RefinementNLP) -> tuple:
    """What names the constraint rows of ``problem``: equal layouts, equal :func:`row_names`.

    The number of waypoints, the joint-step rows (as bytes), the singularity bounds at waypoints
    and inside segments, and the linear rows' places and labels; cheaper to build and to compare
    than the names themselves (one tuple per row), which :func:`names_of` makes from it.
    """
    a = problem.active
    steps = np.ascontiguousarray(problem.step_rows(), dtype=np.int64).tobytes()
    linear = tuple((r.k, r.f, r.label) for r in a.linear_rows)
    return (problem.n_waypoints, steps, a.singular_waypoints, a.singular_segments, linear)


def names_of(layout: tuple) -> list[tuple]:
    """The row names (:func:`row_names`) of the problem whose :func:`row_layout` is ``layout``."""
    N, steps, waypoints, segments, linear = layout
    return (
        [("path", i) for i in range(4 * N)]
        + [("step", i) for i in np.frombuffer(steps, dtype=np.int64).tolist()]
        + [("singular", k, 0.0) for k in waypoints]
        + [("singular", k, f) for k, f in segments]
        + [("row", *key) for key in linear]
    )


class RowMultipliers(Mapping):
    """The multipliers of a problem's constraint rows, by row name (:func:`row_names`), read-only.

    Kept as the values (ng,) in row order with the problem's :func:`row_layout`; the mapping from
    names is made only when asked for. :meth:`in_rows_of` gives them in another problem's row
    order: the values themselves when its layout is the same (its rows have the same names in the
    same order, each name once), else looked up by name, 0 for a row without one.
    """

    def __init__(self, layout: tuple, values: Array) -> None:
        N, steps, waypoints, segments, linear = layout
        self.layout = layout
        self.values = np.asarray(values, dtype=float).ravel()
        if len(self.values) != 4 * N + len(steps) // 8 + len(waypoints) + len(segments) + len(linear):
            raise ValueError(f"{len(self.values)} multipliers for the rows of another problem")
        self._by_name: dict[tuple, float] | None = None

    def _names(self) -> dict[tuple, float]:
        if self._by_name is None:
            self._by_name = dict(zip(names_of(self.layout), self.values.tolist(), strict=True))
        return self._by_name

    def __getitem__(self, key: tuple) -> float:
        return self._names()[key]

    def __iter__(self) -> Iterator[tuple]:
        return iter(self._names())

    def __len__(self) -> int:
        return len(self._names())

    def in_rows_of(self, layout: tuple) -> Array:
        """The multipliers in the row order of the problem with ``layout`` (:func:`row_layout`), (ng,)."""
        if layout == self.layout:
            return self.values.copy()
        by_name = self._names()
        return np.array([by_name.get(key, 0.0) for key in names_of(layout)])


def multipliers_in_rows(lam_g: Mapping, layout: tuple) -> Array:
    """The multipliers ``lam_g`` (by row name) in the row order of the problem with ``layout``, 0 where unnamed."""
    if isinstance(lam_g, RowMultipliers):
        return lam_g.in_rows_of(layout)
    return np.array([lam_g.get(key, 0.0) for key in names_of(layout)])
