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

import numpy as np
from numpy.typing import NDArray

from refine.errors import SolverError
from refine.optimise.problem import RefinementNLP
from refine.optimise.seed import TcpKinematics, ik_chain, reach_shortfall, start_candidates
from refine.optimise.verify import (
    PathCheck,
    Violation,
    check_path,
    runs,
    segment_singularity,
    singularity_measures,
)

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

REACH_TOLERANCE_M = 1e-3
"""A CAD point the best position-only IK misses by more than this is reported out of reach [m]."""

MAX_OUTER_ITERATIONS = 5
"""Rounds of solve -> verify -> add singularity rows before giving up on adding more."""


def _near_singular(kin: TcpKinematics, q: Array, margin: float, active: tuple[int, ...]) -> tuple[int, ...]:
    """Waypoints not in ``active`` with a singularity measure under 1.5x the margin, widened by two."""
    w, _ = singularity_measures(kin, q)
    near = np.flatnonzero(w < 1.5 * margin)
    if near.size == 0:
        return ()
    widened = np.unique(np.clip(near[:, None] + np.arange(-2, 3), 0, len(q) - 1))
    return tuple(sorted(set(widened.tolist()) - set(active)))


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
        iterations: IPOPT iterations, summed over the outer rounds.
        outer_iterations: solve -> verify rounds.
        singular_waypoints: waypoints that carried the singularity bound in the last round.
        singular_segments: (segment, fraction) points inside segments that carried it.
        timings_s: ``seed``, ``solve``, ``verify`` wall times [s], and ``build`` when singularity
            rows had to be added (a rebuild).
    """

    status: str
    reason: str
    q: Array
    q_seed: Array
    check: PathCheck
    solver_status: str
    iterations: int
    outer_iterations: int = 1
    singular_waypoints: tuple[int, ...] = ()
    singular_segments: tuple[tuple[int, float], ...] = ()
    timings_s: dict[str, float] = field(default_factory=dict)


def _targets(problem: RefinementNLP) -> Array:
    targets = np.zeros((problem.n_waypoints, 4, 4))
    targets[:, :3, :3] = problem.fused.rotations
    targets[:, :3, 3] = problem.fused.positions
    targets[:, 3, 3] = 1.0
    return targets


def initial_guess(problem: RefinementNLP, home: Array | None = None) -> Array:
    """IK seed (N, n) [rad] chained along the path, from the best of several first-waypoint starts."""
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)
    lower, upper = problem.lbx[: problem.dof], problem.ubx[: problem.dof]
    qs, _ = ik_chain(kin, _targets(problem), lower, upper, start_candidates(lower, upper, home))
    return qs


def _out_of_reach(problem: RefinementNLP, q_seed: Array, home: Array | None) -> list[Violation]:
    """Runs of waypoints whose CAD point no configuration inside the limits reaches (1 mm test)."""
    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)
    missed = np.linalg.norm(kin.poses(q_seed)[:, :3, 3] - problem.fused.positions, axis=1) > REACH_TOLERANCE_M
    if not missed.any():
        return []
    lower, upper = problem.lbx[: problem.dof], problem.ubx[: problem.dof]
    idx = np.flatnonzero(missed)
    shortfall = np.zeros(problem.n_waypoints)
    shortfall[idx] = reach_shortfall(
        kin, _targets(problem)[idx], lower, upper, start_candidates(lower, upper, home)
    )
    s = problem.fused.s
    return [
        Violation(
            a,
            b,
            float(s[a]),
            float(s[b]),
            "out of reach",
            float(shortfall[a : b + 1].max()),
            "m",
            REACH_TOLERANCE_M,
        )
        for a, b in runs(shortfall > REACH_TOLERANCE_M)
    ]


def solve_refinement(
    problem: RefinementNLP,
    q0: Array | None = None,
    *,
    home: Array | None = None,
) -> Refinement:
    """Solve ``problem`` with IPOPT from ``q0`` (or the IK seed) and verify the answer.

    Args:
        problem: from :func:`refine.optimise.problem.build_refinement`.
        q0: initial joints (N, n) [rad]; None to chain IK from ``home`` and other starts.
        home: preferred first configuration [rad] for the IK seed.

    Raises:
        SolverError: IPOPT itself failed (not an infeasibility): the message names its status.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    q_seed = initial_guess(problem, home) if q0 is None else np.asarray(q0, dtype=float)
    timings["seed"] = time.perf_counter() - t0

    kin = TcpKinematics(problem.robot, problem.base_in_world, problem.tcp_in_flange)
    unreachable = _out_of_reach(problem, q_seed, home)
    timings["seed"] = time.perf_counter() - t0
    if unreachable:
        check = check_path(kin, q_seed, problem.fused, problem.tolerances, problem.axisymmetric)
        reason = "; ".join(v.describe() for v in unreachable)
        log.info("refinement infeasible before solving: %s", reason)
        return Refinement(
            status="infeasible",
            reason=reason,
            q=q_seed,
            q_seed=q_seed,
            check=PathCheck(**{**check.__dict__, "violations": tuple(unreachable) + check.violations}),
            solver_status="not run (out of reach)",
            iterations=0,
            outer_iterations=0,
            timings_s=timings,
        )
    margin = problem.tolerances.singularity_margin
    if margin > 0 and not problem.singular_waypoints:
        near = _near_singular(kin, q_seed, margin, ())
        if near:
            t0 = time.perf_counter()
            problem = problem.with_singularity_bounds(near)
            timings["build"] = time.perf_counter() - t0

    q_start, iterations, timings["solve"], timings["verify"] = q_seed, 0, 0.0, 0.0
    outer = 0
    while outer < MAX_OUTER_ITERATIONS:
        outer += 1
        t0 = time.perf_counter()
        solver = problem.solver
        try:
            sol = solver(
                x0=q_start.ravel(),
                p=problem.params,
                lbx=problem.lbx,
                ubx=problem.ubx,
                lbg=problem.lbg,
                ubg=problem.ubg,
            )
        except RuntimeError as e:
            raise SolverError(f"IPOPT failed to run: {e}") from e
        stats = solver.stats()
        iterations += int(stats.get("iter_count", 0))
        timings["solve"] += time.perf_counter() - t0
        q = np.asarray(sol["x"]).reshape(problem.n_waypoints, problem.dof)

        t0 = time.perf_counter()
        check = check_path(kin, q, problem.fused, problem.tolerances, problem.axisymmetric)
        timings["verify"] += time.perf_counter() - t0
        if not stats.get("success", False):
            break  # more bounds cannot help a problem IPOPT could not solve
        missing = _near_singular(kin, q, margin, problem.singular_waypoints) if margin > 0 else ()
        segments: tuple[tuple[int, float], ...] = ()
        if margin > 0:
            w_between, frac = segment_singularity(kin, q)
            segments = tuple((int(k), float(frac[k])) for k in np.flatnonzero(w_between < 1.5 * margin))
            segments = tuple(sorted(set(segments) - set(problem.singular_segments)))
        if not missing and not segments:
            break
        log.info(
            "singularity bound added on %d waypoints and %d segments; solving again",
            len(missing),
            len(segments),
        )
        t0 = time.perf_counter()
        problem = problem.with_singularity_bounds(missing, segments)
        timings["build"] = timings.get("build", 0.0) + time.perf_counter() - t0
        q_start = q

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
        iterations,
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
        iterations=iterations,
        outer_iterations=outer,
        singular_waypoints=problem.singular_waypoints,
        singular_segments=problem.singular_segments,
        timings_s=timings,
    )
