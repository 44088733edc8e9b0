"""The quality of an answer, the same for every contender: the objective and KKT residuals.

Every contender's joints are evaluated on one NLP: the strict refinement of the problem as
:func:`refine.optimise.problem.build_refinement` states it, with every joint-step row and the rows
the build always holds, and without the rows the outer loop adds for collisions or singularities
(the clearance is the verification's ``min_clearance_m``). Its variables are the joints, so any
answer ``q`` (N, n) is a point ``x = vec(q)`` of it (waypoint by waypoint). At that point:

* ``objective``: the refinement's cost ``f(x)`` (a mean over waypoints, in deg², as
  :class:`refine.optimise.problem.Weights` defines it).
* ``primal_residual``: the largest bound violation of a constraint row or a variable,
  ``max(lbg - g, g - ubg, lbx - x, x - ubx, 0)``, in the rows' own units (metres for the TCP
  position, cosine for the orientation cone, radians for joints and joint steps).
* ``dual_residual``: ``||∇f + Jᵀλ + ν||∞`` at multipliers that satisfy the sign and
  complementarity conditions at ``x``: only a row or variable within :data:`ACTIVE_TOL` of a bound
  may carry one, ``>= 0`` at an upper bound, ``<= 0`` at a lower, free for an equality (CasADi's
  convention). The multipliers are estimated from ``x`` alone, so no contender's own are needed:
  least squares (SciPy's ``lsmr``), repeated with the multipliers of the wrong sign fixed at 0
  (:data:`SIGN_PASSES`), then clipped to their signs. The estimate is admissible, so the residual
  bounds the least one from above: a small figure shows the answer near a KKT point, a large one
  may overstate its distance from one. Unscaled, in the objective's units per radian (the objective is a mean over
  waypoints, so its gradient shrinks as 1/N).

A stationary tool (a problem the refinement does not state) has no such NLP: the columns are empty.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import lsmr

from refine.bench.suites import BenchProblem
from refine.types import Array

ACTIVE_TOL = 1e-6
"""A row or variable this close to a bound (in its own units) may carry a multiplier."""

SIGN_PASSES = 8
"""Least-squares passes of the multiplier estimate; each drops the multipliers of the wrong sign."""

LSMR_TOL = 1e-12
"""Stopping tolerances (``atol``, ``btol``) of each least-squares pass."""

LSMR_MAX_ITER = 20000
"""Iteration cap of each least-squares pass."""


@dataclass(frozen=True)
class Quality:
    """The quality columns of one answer (NaN where it has no meaning).

    Attributes:
        objective: the refinement's cost at the answer [deg²].
        primal_residual: the largest bound violation (units of the row, see the module).
        dual_residual: the least stationarity residual over admissible multipliers [deg²/rad].
    """

    objective: float
    primal_residual: float
    dual_residual: float


NONE = Quality(np.nan, np.nan, np.nan)


def shared_nlp(problem: BenchProblem):
    """The strict refinement NLP of ``problem`` with every joint-step row, made once per problem."""
    if "quality_nlp" not in problem.extra:
        problem.extra["quality_nlp"] = problem.refinement("assembled", joint_steps="all")
    return problem.extra["quality_nlp"]


def evaluate(problem: BenchProblem, q: Array | None) -> Quality:
    """The objective and KKT residuals of joints ``q`` (N, n) [rad] on the shared NLP (see the module)."""
    if q is None or problem.tool_in_world is not None:
        return NONE
    q = np.asarray(q, dtype=float)
    if q.shape != (problem.n_waypoints, problem.robot.nq) or not np.all(np.isfinite(q)):
        return NONE
    nlp = shared_nlp(problem)
    x = q.ravel()
    if len(x) != len(nlp.lbx):
        return NONE
    f, grad = nlp.derivatives["grad_f"](x, nlp.params)
    g, jac = nlp.derivatives["jac_g"](x, nlp.params)
    g = np.asarray(g).ravel()
    grad = np.asarray(grad).ravel()
    lbg, ubg, lbx, ubx = (np.asarray(b, dtype=float) for b in (nlp.lbg, nlp.ubg, nlp.lbx, nlp.ubx))
    primal = max(0.0, float(np.max(lbg - g, initial=0.0)), float(np.max(g - ubg, initial=0.0)))
    primal = max(primal, float(np.max(lbx - x, initial=0.0)), float(np.max(x - ubx, initial=0.0)))
    dual = _dual_residual(grad, _csc(jac), g, lbg, ubg, x, lbx, ubx)
    return Quality(float(f), primal, dual)


def _csc(m) -> sparse.csc_matrix:
    """A CasADi sparse matrix as SciPy's."""
    sp = m.sparsity()
    return sparse.csc_matrix(
        (np.asarray(m.nonzeros(), dtype=float), sp.row(), sp.colind()), shape=(m.size1(), m.size2())
    )


def _signs(value: Array, lower: Array, upper: Array) -> tuple[Array, Array, Array]:
    """Which entries may carry a multiplier, and its lower and upper bound (CasADi's sign convention)."""
    at_lower = value - lower <= ACTIVE_TOL
    at_upper = upper - value <= ACTIVE_TOL
    active = at_lower | at_upper
    lo = np.where(at_lower, -np.inf, 0.0)
    hi = np.where(at_upper, np.inf, 0.0)
    return active, lo[active], hi[active]


def _dual_residual(
    grad: Array, jac: sparse.csc_matrix, g: Array, lbg: Array, ubg: Array, x: Array, lbx: Array, ubx: Array
) -> float:
    """``min ||∇f + Jᵀλ + ν||∞`` over admissible λ (rows) and ν (variables), by bounded least squares."""
    rows, lo_g, hi_g = _signs(g, lbg, ubg)
    cols, lo_x, hi_x = _signs(x, lbx, ubx)
    blocks = [jac[rows].T.tocsc(), sparse.identity(len(x), format="csc")[:, np.flatnonzero(cols)]]
    m = sparse.hstack(blocks, format="csc")
    if m.shape[1] == 0:
        return float(np.max(np.abs(grad), initial=0.0))
    lo, hi = np.concatenate([lo_g, lo_x]), np.concatenate([hi_g, hi_x])
    free = np.ones(m.shape[1], dtype=bool)
    lam = np.zeros(m.shape[1])
    for _ in range(SIGN_PASSES):
        lam[:] = 0.0
        lam[free] = lsmr(m[:, free], -grad, atol=LSMR_TOL, btol=LSMR_TOL, maxiter=LSMR_MAX_ITER)[0]
        wrong = free & ((lam < lo) | (lam > hi))
        if not wrong.any():
            break
        free &= ~wrong
    lam = np.clip(lam, lo, hi)  # admissible in any case: the residual is that of an admissible estimate
    return float(np.max(np.abs(grad + m @ lam), initial=0.0))
