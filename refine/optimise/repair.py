"""The repair: a strict solve, then the least extra orientation slack when it has no answer.

The repair: a strict solve from a seed and, when it has no answer and repair is on, the elastic
problem that finds the smallest extra orientation slack per waypoint (an exact L1 penalty); the
segments that needed slack are reported with the constraint that forced it
(:func:`solve_with_repair`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping

import numpy as np

from refine.optimise.diagnosis import Finding
from refine.optimise.outcome import Refinement, Repair, describe_check, findings_of, problem_kinematics
from refine.optimise.problem import ActiveSet, ConstraintSource, RefinementNLP
from refine.optimise.rounds import (
    SOLVER_LABELS,
    RoundLoop,
    new_joint_steps,
    new_singular_points,
    run_rounds,
    singular_around,
    with_joint_steps,
)
from refine.optimise.verify import (
    check_path,
)
from refine.stopwatch import StageTimes, add_time
from refine.types import Array

log = logging.getLogger(__name__)


ELASTIC_ONLY = "not run (the elastic problem answers it: another IK branch, after the first failed)"
"""Why the strict solve is skipped on the IK branches tried after the first: with repair on, the
elastic problem's answer without slack is the strict problem's, so one solve does for both."""


def solve_with_repair(
    problem: RefinementNLP,
    q_seed: Array,
    sources: tuple[ConstraintSource, ...],
    repair_max_slack_deg: float | None,
    max_rounds: int,
    timings: dict[str, float],
    deadline: float = math.inf,
    skip_strict: str = "",
    stretched: Array | None = None,
    multipliers: tuple[Mapping[tuple, float], Array] | None = None,
    first_options: dict | None = None,
    seed_jacobians: Array | None = None,
) -> Refinement:
    """Strict solve from ``q_seed``, then the elastic repair when the strict problem fails.

    With ``skip_strict`` (why the strict solve is not run: it is known to be infeasible, or the
    elastic problem answers it) the repair starts at once; an elastic answer that verifies without
    any slack is then ``ok``.
    ``stretched`` (N,) marks the waypoints whose wrist centre the demonstration puts near or beyond
    the end of the arm's range: the singularity bound holds there from the first solve (at and
    between the waypoints), so the elbow cannot pass through its stretched singularity while the
    solver pulls the wrist in. ``multipliers`` (a previous solve's of the same rows, see
    :class:`RoundLoop`) warm-start the first strict solve. ``first_options`` (solver options) hold
    for the first strict solve only, less the keys the problem's caller gave; the later rounds and
    the elastic problem are built with the problem's own options. ``seed_jacobians``: the TCP
    Jacobians (N, 6, n) at ``q_seed`` when the caller has them (a warm seed's projection), or None.
    """
    kin = problem_kinematics(problem)
    loop = RoundLoop(problem, timings, max_rounds=max_rounds, deadline=deadline, multipliers=multipliers)
    start = StageTimes.clock()  # the constraints the seed shows to be needed count as seeding
    initial = new_singular_points(
        kin, q_seed, problem.tolerances.singularity_margin, problem.active, jacobians=seed_jacobians
    )
    if stretched is not None and stretched.any() and problem.tolerances.singularity_margin > 0:
        initial = initial.union(singular_around(stretched))
    seed_rows = tuple(r for src in sources for r in src.rows(problem, q_seed))
    seed_steps = new_joint_steps(problem, q_seed)
    add_time(timings, "seed", start)
    first = {k: v for k, v in (first_options or {}).items() if k not in problem.given_options}
    if first and not skip_strict:
        loop.base_options = {**problem.solver_options, **first}
    if initial.singular_waypoints or initial.singular_segments or seed_rows or seed_steps:
        loop.rebuild(
            active=problem.active.union(
                ActiveSet(initial.singular_waypoints, initial.singular_segments, seed_rows)
            ),
            joint_steps=with_joint_steps(problem, seed_steps),
        )
    elif loop.base_options is not None:
        loop.rebuild()
    loop.base_options = dict(problem.solver_options)  # every later build: the problem's own options
    used = {} if skip_strict else dict(loop.problem.solver_options)
    if skip_strict:
        q = q_seed
        slack = np.zeros(problem.n_waypoints)
        check = check_path(kin, q, problem.fused, problem.tolerances, problem.axisymmetric)
        stats = {"return_status": skip_strict}
        strict_reason = skip_strict
    else:
        x, stats, check, slack = run_rounds(loop, q_seed.ravel(), sources, warm=multipliers is not None)
        q = loop.problem.joints(x)
        strict_reason = describe_check(check, stats)
    status = "ok" if check.ok and not skip_strict else "infeasible"
    repairs: tuple[Repair, ...] = ()
    strict_problem = None

    if status == "infeasible" and repair_max_slack_deg is not None and repair_max_slack_deg > 0:
        strict_problem = loop.problem  # its rows are the elastic problem's: a re-solve's start
        loop.rebuild(active=loop.problem.active, elastic_deg=repair_max_slack_deg)
        used = used or dict(loop.problem.solver_options)
        # start from the seed (on the path, orientation off only where the limits clamped it), with
        # each slack at what that start needs, so IPOPT begins feasible wherever it can
        q_start = q_seed
        clock = StageTimes.clock()
        start = check_path(kin, q_start, problem.fused, problem.tolerances, problem.axisymmetric)
        cos_needed = math.cos(math.radians(problem.tolerances.orientation_deg)) - np.cos(
            np.radians(start.orientation_deviation_deg)
        )
        sigma0 = np.clip(cos_needed, 0.0, loop.problem.ubx[problem.n_waypoints * problem.dof :])
        add_time(timings, "solve", clock)
        x, stats, check, slack = run_rounds(loop, np.concatenate([q_start.ravel(), sigma0]), sources)
        q = loop.problem.joints(x)
        if check.ok:
            status = "repaired"
            if skip_strict == ELASTIC_ONLY and slack.max() <= 1e-3:
                # the elastic problem found an answer without slack: ok if it verifies strictly
                strict = check_path(kin, q, problem.fused, problem.tolerances, problem.axisymmetric)
                extra = tuple(v for src in sources for v in src.violations(loop.problem, q))
                if strict.ok and not extra:
                    status, check, slack = "ok", strict, np.zeros(problem.n_waypoints)
        else:
            log.info("repair within %.1f deg failed: %s", repair_max_slack_deg, describe_check(check, stats))
            note = f"no repair within {repair_max_slack_deg:g} deg of extra slack"
            stats = {
                **stats,
                "return_status": f"{stats.get('return_status')}; {note} (strict: {strict_reason})",
            }

    solver_status = str(stats.get("return_status", "unknown"))
    if status == "ok" and not stats.get("success", False):
        log.warning(
            "%s returned %s but the verified path meets every tolerance",
            SOLVER_LABELS[problem.solver_name],
            solver_status,
        )
    t0, c0 = StageTimes.clock()
    findings: tuple[Finding, ...] = ()
    if status == "repaired":
        findings = findings_of(problem, sources, status, q, slack > 1e-3, slack)
        repairs = tuple(
            Repair(
                f.index_start,
                f.index_end,
                f.s_start_m,
                f.s_end_m,
                float(f.slack_deg or 0.0),
                f.cause.label,
                f.cause.objects,
            )
            for f in findings
        )
    elif status == "infeasible":
        mask = np.zeros(problem.n_waypoints, dtype=bool)
        for v in check.violations:
            mask[v.index_start : v.index_end + 1] = True
        findings = findings_of(problem, sources, status, q, mask)
    add_time(timings, "diagnose", (t0, c0))
    reason = (
        ""
        if status == "ok"
        else "; ".join(f.describe() for f in findings) + f" ({describe_check(check, stats)})"
        if status == "infeasible"
        else "; ".join(f.describe() for f in findings)
    )
    return Refinement(
        status=status,
        reason=reason,
        q=q,
        q_seed=q_seed,
        check=check,
        solver_status=solver_status,
        iterations=loop.iterations,
        outer_iterations=loop.outer,
        active=loop.problem.active,
        slack_deg=slack if status == "repaired" else np.zeros(problem.n_waypoints),
        repairs=repairs,
        timings_s=timings,
        diagnosis=findings,
        problem=loop.problem,
        multipliers=loop.multipliers,
        first_options=used,
        strict_problem=strict_problem if loop.problem.elastic_deg is not None else None,
    )
