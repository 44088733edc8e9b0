"""The outer rounds of a solve: solve, verify, add what binds, solve again.

The outer rounds of a solve: solve, verify with Pinocchio, add the constraints that bind only in
places (singularity bounds, clearance rows from the constraint sources, joint-step rows) and solve
again, warm-started, until the verified path needs nothing more (:func:`run_rounds`). The first
solve of a re-solve from a previous answer's multipliers is first tried as a Newton correction
(:mod:`refine.optimise.correction`), IPOPT solving where it is refused.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from refine.control import after_solve, check_cancelled, enter_round, out_of_time, stage_done
from refine.errors import SolverError
from refine.optimise.correction import RowMultipliers, correct, multipliers_in_rows, row_layout
from refine.optimise.outcome import TimeLimitReached, problem_kinematics
from refine.optimise.problem import ActiveSet, ConstraintSource, LinearRow, RefinementNLP
from refine.optimise.verify import (
    PathCheck,
    check_path,
    segment_singularity,
    singularity_measures,
)
from refine.robot.kinematics import TcpKinematics
from refine.stopwatch import StageTimes, add_time
from refine.types import Array

log = logging.getLogger(__name__)


WARM_MU_INIT = 1e-4
"""IPOPT's initial barrier parameter when a round starts from the last round's answer and
multipliers (its default, 0.1, pushes a warm start off the constraints it had found active)."""


FATROP_REPAIR_MU_INIT = 1e-6
"""fatrop's initial barrier parameter in a round after the first and in the repair (see
:data:`refine.optimise.stagewise.FATROP_DEFAULTS`)."""


CORRECTED = "Solve_Succeeded (Newton correction of the previous answer)"
"""The solver status of a round answered by :func:`refine.optimise.correction.correct`."""


SOLVER_LABELS = {"ipopt": "IPOPT", "fatrop": "fatrop"}
"""How messages name each solver of :data:`refine.settings.SOLVERS`."""


MAX_OUTER_ITERATIONS = 8


STEP_NEAR = 0.5
"""A problem built with only some joint-step rows gets the row of every joint step larger than
this fraction of the bound, in the seed and in each answer; an answer with a step that large
outside the rows is solved again with them. Steps under the bound do not bind, so the answer is the
complete problem's."""


def new_singular_points(
    kin: TcpKinematics,
    q: Array,
    margin: float,
    active: ActiveSet,
    check: PathCheck | None = None,
    jacobians: Array | None = None,
) -> ActiveSet:
    """Waypoints and segment points near the singularity not yet bounded in ``active``.

    ``check``: the check of ``q`` (:func:`refine.optimise.verify.check_path`), whose measures at the
    waypoints and inside the segments are these (the same functions of the same joints), or None
    to compute them. ``jacobians``: the TCP Jacobians (N, 6, n) at ``q`` when the caller has them
    (a warm seed's projection, :func:`refine.optimise.warm.warm_seed`), or None.
    """
    if margin <= 0:
        return ActiveSet()
    if check is not None and check.singularity_between_at is not None:
        w, w_between, frac = check.singularity, check.singularity_between, check.singularity_between_at
    else:
        w = singularity_measures(kin, q, smallest=False, jacobians=jacobians)[0]
        w_between, frac = segment_singularity(kin, q)
    near = np.flatnonzero(w < 1.5 * margin)
    widened = np.unique(np.clip(near[:, None] + np.arange(-2, 3), 0, len(q) - 1)) if near.size else near
    waypoints = tuple(sorted(set(widened.tolist()) - set(active.singular_waypoints)))
    points = {(int(k), float(frac[k])) for k in np.flatnonzero(w_between < 1.5 * margin)}
    return ActiveSet(waypoints, tuple(sorted(points - set(active.singular_segments))))


def new_joint_steps(problem: RefinementNLP, q: Array) -> tuple[int, ...]:
    """Joint-step rows ``k·n + j`` near their bound in ``q`` (N, n) that ``problem`` does not hold."""
    if problem.joint_steps == "all":
        return ()
    step = math.radians(problem.tolerances.joint_step_deg)
    near = np.flatnonzero(np.abs(np.diff(q, axis=0)).ravel() > min(STEP_NEAR, 1.0) * step)
    return tuple(sorted(set(near.tolist()) - set(problem.joint_steps)))


def with_joint_steps(problem: RefinementNLP, more: tuple[int, ...]) -> tuple[int, ...] | None:
    """The joint-step rows of ``problem`` and ``more``, or None when nothing is added."""
    return tuple(sorted(set(problem.joint_steps) | set(more))) if more else None


def singular_around(mask: Array, widen: int = 2) -> ActiveSet:
    """Singularity bounds at the waypoints of ``mask`` (N,) widened by ``widen``, and mid-segment."""
    N = len(mask)
    idx = np.flatnonzero(mask)
    idx = np.unique(np.clip(idx[:, None] + np.arange(-widen, widen + 1), 0, N - 1))
    return ActiveSet(tuple(int(k) for k in idx), tuple((int(k), 0.5) for k in idx if k < N - 1))


WARM_START_OPTIONS = {"ipopt.mu_init": WARM_MU_INIT, "fatrop.mu_init": FATROP_REPAIR_MU_INIT}
"""Solver options of a round that starts from the last round's answer (and, for IPOPT, multipliers),
unless the problem's caller gave the same option (:attr:`RefinementNLP.given_options`)."""


ELASTIC_OPTIONS = {"ipopt.mu_strategy": "monotone", "fatrop.mu_init": FATROP_REPAIR_MU_INIT}
"""Solver options of the elastic (repair) problem unless its caller gave them (IPOPT's reasons below). Its start is far from the answer (the seed needs
several degrees more slack than the repair) and near the stretched elbow or a wrist singularity;
the adaptive barrier strategy drops the barrier to 1e-6 within ten iterations there and then crawls
(300 iterations without convergence on 2 of 20 noisy copies of ``reach_tilt``), while Fiacco-McCormick's
monotone decrease converges in about 40 (the same answer where both converge)."""


@dataclass
class RoundLoop:
    """The state of one solve's outer rounds: the problem as grown so far, its multipliers, times and counts."""

    problem: RefinementNLP
    timings: dict[str, float]
    iterations: int = 0
    outer: int = 0
    max_rounds: int = MAX_OUTER_ITERATIONS
    deadline: float = math.inf
    multipliers: tuple[dict[tuple, float], Array] | None = None
    base_options: dict | None = None

    def solve(self, x0: Array, warm: bool = False) -> tuple[Array, dict]:
        """Solve from ``x0``; ``warm``: with the last solve's multipliers, row by row."""
        start = StageTimes.clock()
        if start[0] >= self.deadline or out_of_time():
            raise TimeLimitReached
        check_cancelled("solve")
        p = self.problem
        layout = row_layout(p)  # the same rows name the start multipliers and the answer's
        extra = {}
        if warm and self.multipliers is not None:
            lam_g, lam_x = self.multipliers
            extra["lam_g0"] = multipliers_in_rows(lam_g, layout)
            if len(lam_x) == len(p.lbx):
                extra["lam_x0"] = lam_x
        name = SOLVER_LABELS[p.solver_name]
        if warm and self.outer <= 1 and "lam_x0" in extra and p.solver_name == "ipopt":
            corrected = self._corrected(x0, extra["lam_g0"], extra["lam_x0"], layout, start)
            if corrected is not None:
                return corrected
        if p.watch is not None:
            p.watch.iteration, p.watch.interrupted, p.watch.deadline = 0, False, self.deadline
        try:
            sol = p.solver(x0=x0, p=p.params, lbx=p.lbx, ubx=p.ubx, lbg=p.lbg, ubg=p.ubg, **extra)
        except RuntimeError as e:
            raise SolverError(f"{name} failed to run: {e}") from e
        stats = {**p.solver.stats(), "solver": name}
        after_solve(str(stats.get("return_status", "unknown")), p.watch is not None and p.watch.interrupted)
        self.multipliers = (
            RowMultipliers(layout, np.asarray(sol["lam_g"])),
            np.asarray(sol["lam_x"]).ravel(),
        )
        status = str(stats.get("return_status", "unknown"))
        if status in {"Invalid_Option", "Invalid_Problem_Definition", "Insufficient_Memory"}:
            raise SolverError(f"{name} could not solve the refinement: {status}")
        if status == "Maximum_WallTime_Exceeded" or time.perf_counter() >= self.deadline or out_of_time():
            add_time(self.timings, "solve", start)
            raise TimeLimitReached
        self.iterations += int(stats.get("iter_count", 0))
        add_time(self.timings, "solve", start)
        return np.asarray(sol["x"]).ravel(), stats

    def _corrected(
        self, x0: Array, lam_g0: Array, lam_x0: Array, layout: tuple, start: tuple[float, float]
    ) -> tuple[Array, dict] | None:
        """The answer by Newton correction from ``x0`` and the previous multipliers, or None (logged why).

        ``layout``: the problem's :func:`refine.optimise.correction.row_layout`, which keys the answer's multipliers.

        See :mod:`refine.optimise.correction`: accepted only as an answer of the whole problem.
        """
        found, reason = correct(self.problem, x0, lam_g0, lam_x0)
        if found is None:
            log.debug("Newton correction refused, solved with IPOPT: %s", reason)
            return None
        self.multipliers = (RowMultipliers(layout, found.lam_g), found.lam_x)
        self.iterations += found.iterations
        add_time(self.timings, "solve", start)
        stats = {
            "return_status": CORRECTED,
            "success": True,
            "iter_count": found.iterations,
            "solver": "Newton correction",
        }
        return found.x, stats

    def rebuild(self, warm: bool = False, **changes) -> None:
        """Rebuild with ``changes``; ``warm``: for a solve that starts at the last answer."""
        start = StageTimes.clock()
        if self.base_options is None:
            self.base_options = dict(self.problem.solver_options)
        options = dict(self.base_options)
        if changes.get("elastic_deg") is not None:
            options.update(ELASTIC_OPTIONS)
        if warm:
            options.update(WARM_START_OPTIONS)
        options.update(self.problem.given_options)  # the caller's options win over a round's own
        self.problem = replace(self.problem, solver_options=options).rebuilt(**changes)
        add_time(self.timings, "build", start)


def run_rounds(
    loop: RoundLoop, x0: Array, sources: tuple[ConstraintSource, ...], *, warm: bool = False
) -> tuple[Array, dict, PathCheck, Array]:
    """Solve, verify and grow the active set until nothing more is needed (or the rounds run out).

    ``warm``: the first solve starts from the loop's multipliers (a previous solve's, re-solving).
    """
    kin = problem_kinematics(loop.problem)
    margin = loop.problem.tolerances.singularity_margin
    while True:
        loop.outer += 1
        enter_round(loop.outer)
        x, stats = loop.solve(x0, warm)
        p = loop.problem
        q, slack = p.joints(x), p.slack_deg(x)
        start = StageTimes.clock()
        check = check_path(
            kin, q, p.fused, p.tolerances, p.axisymmetric, slack if p.elastic_deg is not None else None
        )
        extra = [v for src in sources for v in src.violations(p, q)]
        if extra:
            check = replace(check, violations=check.violations + tuple(extra))
        add_time(loop.timings, "verify", start)
        stage_done("verify")
        if not stats.get("success", False) or loop.outer >= loop.max_rounds:
            return x, stats, check, slack
        start = StageTimes.clock()  # finding what the next round adds is the outer loop's solving
        more = new_singular_points(kin, q, margin, p.active, check)
        rows = tuple(r for src in sources for r in src.rows(p, q))
        steps = new_joint_steps(p, q)
        add_time(loop.timings, "solve", start)
        if not (more.singular_waypoints or more.singular_segments or rows or steps):
            return x, stats, check, slack
        log.info(
            "outer round %d: +%d singular waypoints, +%d segment points, %d linear rows, +%d joint steps",
            loop.outer,
            len(more.singular_waypoints),
            len(more.singular_segments),
            len(rows),
            len(steps),
        )
        # rows accumulate, a pair's fresh linearisation at the same point replacing its old one:
        # replacing whole rounds lets the path swing between two sides of an obstacle
        grown = p.active.union(ActiveSet(more.singular_waypoints, more.singular_segments))
        active = ActiveSet(
            grown.singular_waypoints, grown.singular_segments, merge_rows(p.active.linear_rows, rows)
        )
        loop.rebuild(
            warm=True, active=active, elastic_deg=p.elastic_deg, joint_steps=with_joint_steps(p, steps)
        )
        x0, warm = (x if p.elastic_deg is not None else q.ravel()), True


def merge_rows(old: tuple[LinearRow, ...], new: tuple[LinearRow, ...]) -> tuple[LinearRow, ...]:
    """The rows of ``old`` and ``new``, a row of ``new`` replacing the one of ``old`` at the same place."""
    merged = {(r.k, r.f, r.label): r for r in old}
    merged.update({(r.k, r.f, r.label): r for r in new})
    return tuple(merged.values())
