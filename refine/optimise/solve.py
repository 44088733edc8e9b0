"""Solve a built refinement NLP with IPOPT and verify the answer with Pinocchio.

:func:`initial_guess` chains IK along the path; :func:`solve_refinement` runs IPOPT from it and
checks the result numerically (:mod:`refine.optimise.verify`) before reporting ``ok``. A problem
IPOPT cannot satisfy, or whose answer fails the check, is reported ``infeasible`` with the
segments and the binding reason.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from refine.errors import SolverError
from refine.optimise.problem import RefinementNLP
from refine.optimise.seed import TcpKinematics, ik_chain, start_candidates
from refine.optimise.verify import PathCheck, check_path

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

IPOPT_DEFAULTS: dict[str, Any] = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "ipopt.tol": 1e-9,
    "ipopt.constr_viol_tol": 1e-10,
    "ipopt.max_iter": 300,
    "ipopt.mu_strategy": "adaptive",
    "ipopt.warm_start_init_point": "yes",
    "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
}


@dataclass(frozen=True)
class Refinement:
    """The outcome of a refinement.

    Attributes:
        status: ``"ok"`` or ``"infeasible"``.
        reason: empty when ok; otherwise why, naming segments, constraint and figures.
        q: joints per waypoint [rad], shape (N, n).
        q_seed: the IK seed the solver started from [rad], shape (N, n).
        check: the numeric verification of ``q``.
        solver_status: IPOPT's return status.
        iterations: IPOPT iterations.
        timings_s: ``seed``, ``solve``, ``verify`` wall times [s].
    """

    status: str
    reason: str
    q: Array
    q_seed: Array
    check: PathCheck
    solver_status: str
    iterations: int
    timings_s: dict[str, float] = field(default_factory=dict)


def initial_guess(problem: RefinementNLP, home: Array | None = None) -> Array:
    """IK seed (N, n) [rad] chained along the path, from the best of several first-waypoint starts."""
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)
    targets = np.zeros((problem.n_waypoints, 4, 4))
    targets[:, :3, :3] = problem.fused.rotations
    targets[:, :3, 3] = problem.fused.positions
    targets[:, 3, 3] = 1.0
    lower = problem.lbx[: problem.dof]
    upper = problem.ubx[: problem.dof]
    qs, _ = ik_chain(kin, targets, lower, upper, start_candidates(lower, upper, home))
    return qs


def solve_refinement(
    problem: RefinementNLP,
    q0: Array | None = None,
    *,
    home: Array | None = None,
    solver_options: dict[str, Any] | None = None,
) -> Refinement:
    """Solve ``problem`` with IPOPT from ``q0`` (or the IK seed) and verify the answer.

    Args:
        problem: from :func:`refine.optimise.problem.build_refinement`.
        q0: initial joints (N, n) [rad]; None to chain IK from ``home`` and other starts.
        home: preferred first configuration [rad] for the IK seed.
        solver_options: CasADi/IPOPT options overriding :data:`IPOPT_DEFAULTS`.

    Raises:
        SolverError: IPOPT itself failed (not an infeasibility): the message names its status.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    q_seed = initial_guess(problem, home) if q0 is None else np.asarray(q0, dtype=float)
    timings["seed"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    opts = {**IPOPT_DEFAULTS, **(solver_options or {})}
    solver = ca.nlpsol("refine", "ipopt", problem.nlp, opts)
    try:
        sol = solver(
            x0=q_seed.ravel(),
            p=problem.params,
            lbx=problem.lbx,
            ubx=problem.ubx,
            lbg=problem.lbg,
            ubg=problem.ubg,
        )
    except RuntimeError as e:
        raise SolverError(f"IPOPT failed to run: {e}") from e
    stats = solver.stats()
    timings["solve"] = time.perf_counter() - t0
    q = np.asarray(sol["x"]).reshape(problem.n_waypoints, problem.dof)

    t0 = time.perf_counter()
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)
    check = check_path(kin, q, problem.fused, problem.tolerances, problem.axisymmetric)
    timings["verify"] = time.perf_counter() - t0

    solver_status = str(stats.get("return_status", "unknown"))
    if solver_status in {"Invalid_Option", "Invalid_Problem_Definition", "Insufficient_Memory"}:
        raise SolverError(f"IPOPT could not solve the refinement: {solver_status}")
    if check.ok:
        status, reason = "ok", ""
        if not stats.get("success", False):
            log.warning("IPOPT returned %s but the verified path meets every tolerance", solver_status)
    else:
        status = "infeasible"
        reason = f"IPOPT: {solver_status}; " + "; ".join(v.describe() for v in check.violations[:10])
        if len(check.violations) > 10:
            reason += f"; and {len(check.violations) - 10} more segments"
    log.info(
        "refinement %s after %d IPOPT iterations (seed %.3f s, solve %.3f s)",
        status,
        stats.get("iter_count", -1),
        timings["seed"],
        timings["solve"],
    )
    return Refinement(
        status=status,
        reason=reason,
        q=q,
        q_seed=q_seed,
        check=check,
        solver_status=solver_status,
        iterations=int(stats.get("iter_count", -1)),
        timings_s=timings,
    )
