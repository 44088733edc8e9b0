"""Solve a built refinement NLP with its solver (IPOPT, or fatrop), verify the answer, and repair it when it is infeasible.

The loop: chain IK for a seed (reporting points out of reach at once), solve, verify with plain
Pinocchio (:mod:`refine.optimise.verify`), add the constraints that only bind in places (the
singularity bound at waypoints and inside segments near a singularity, linearised clearance rows
from a :class:`ConstraintSource` such as the collision model) and solve again until the verified
path needs nothing more. When the strict problem has no answer and repair is on, the elastic problem
finds the smallest extra orientation slack per waypoint that makes it feasible (an exact L1
penalty), and the segments that needed slack are reported with the constraint that forced it.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace

import numpy as np

from refine.control import out_of_time
from refine.errors import SolverError
from refine.optimise.coarse import (
    COARSE_SEEDED_MU_INIT,
    coarse_copy,
    coarse_waypoints,
    ladder_waypoints,
    projected,
)
from refine.optimise.diagnosis import reach_tilts
from refine.optimise.outcome import (
    Refinement,
    TimeLimitReached,
    findings_of,
    problem_bounds,
    problem_kinematics,
    problem_targets,
    timed_out,
    unsolved,
)
from refine.optimise.problem import ConstraintSource, RefinementNLP
from refine.optimise.repair import ELASTIC_ONLY, solve_with_repair
from refine.optimise.rounds import MAX_OUTER_ITERATIONS
from refine.optimise.seed import (
    alternative_seeds,
    chained_seed,
    initial_guess,
    out_of_reach,
    remembering_chains,
    start_candidates,
)
from refine.optimise.steady import rank_chains, steady_branch, turn_over_step, whole_chain
from refine.optimise.verify import (
    check_path,
)
from refine.optimise.warm import WarmStart, rebuilt_like, reuse_final, warm_seed
from refine.robot.kinematics import CONVERGED
from refine.stopwatch import StageTimes, add_time
from refine.types import Array

log = logging.getLogger(__name__)


SEED_INSET_M = 0.05
"""The IK seed tilts a pose out of reach until its wrist centre is this far inside the arm's range
[m]: off the stretched elbow, which is a singularity."""

TILT_TOLERANCE_DEG = 0.1
"""A reach tilt counts as beyond the cone (or the cone + slack) by more than this [deg] (the tilt is
searched in 0.1 deg steps)."""


FATROP_FAILED = "not solved (return flag"
"""How fatrop's status begins when it stopped without converging (:mod:`refine.optimise.stagewise`)."""

FATROP_HINT = (
    "fatrop stopped without converging in at least one solve, so this verdict may be the solver's, not "
    "the problem's: fatrop has no restoration phase and can fail from a start that breaks a row, "
    "where IPOPT succeeds; run again with [optimise] solver = 'ipopt'"
)
"""Appended to the reason of an infeasible refinement in which fatrop failed to converge."""


BRANCH_CANDIDATES = 2
"""Other IK branches chained per branch tried when the first gives no answer; the best are tried
(:func:`rank_chains`)."""


SAME_SEED_RAD = 1e-6
"""An IK branch's seed within this [rad] of a seed whose elastic repair has already failed, at every
waypoint and joint, is that seed: its verdict is known and it is not solved again. The chains are
remembered within a refinement (:func:`refine.optimise.seed.remembering_chains`), so a branch that
chains onto the same joints repeats them to the bit (``joint_wrap_infeasible``: the third branch's
seed is the first's, 0 rad apart, where the second's is 3.14 rad from it)."""


class CoarseTimeLimit(TimeLimitReached):
    """The time limit ran out in a coarse copy's solve, or before it could start.

    ``spent``: per copy reached, its waypoints and its solve's wall-clock start and end
    (:func:`time.perf_counter` [s]; the end None for a copy not started).
    """

    def __init__(self, spent: list[tuple[int, float, float | None]]) -> None:
        super().__init__(spent)
        self.spent = spent


# ---- the outer loop ------------------------------------------------------------------------------


@remembering_chains
def solve_refinement(
    problem: RefinementNLP,
    q0: Array | None = None,
    *,
    home: Array | None = None,
    sources: tuple[ConstraintSource, ...] = (),
    repair_max_slack_deg: float | None = None,
    max_rounds: int = MAX_OUTER_ITERATIONS,
    max_branches: int = 3,
    time_limit_s: float | None = None,
    warm: WarmStart | None = None,
    first_options: dict | None = None,
    raise_on_timeout: bool = False,
) -> Refinement:
    """Solve ``problem`` with its solver from ``q0`` (or the IK seed), verify, and repair if asked.

    When the answer from the seed's IK branch is infeasible (even repaired), the first waypoint's
    other IK branches are chained and tried in turn, up to ``max_branches`` in all.

    Args:
        problem: from :func:`refine.optimise.problem.build_refinement` (strict).
        q0: initial joints (N, n) [rad]; None to chain IK from ``home`` and other starts.
        home: preferred first configuration [rad] for the IK seed.
        sources: constraint sources (collision) adding linearised rows and dense checks.
        repair_max_slack_deg: when the strict problem is infeasible, the largest extra orientation
            slack [deg] the elastic problem may use; None for no repair.
        max_rounds: solve -> verify -> add constraints rounds at most.
        max_branches: IK branches of the first waypoint to try (only when ``q0`` is None).
        time_limit_s: wall-time budget [s] of the solves; when it runs out before any verdict the
            result is ``timeout`` with ``time_limit_reached`` set and a reason saying so; when it
            runs out while other IK branches are tried, the first branch's verdict stands. Build
            the problem with ``ipopt.max_wall_time`` at most this; each IPOPT solve also stops at
            the deadline through its iteration callback (:mod:`refine.optimise.watch`).
            The coarse copies that seed a redundant arm (:func:`coarse_seed`) are solved within it,
            each with the time left as its ``ipopt.max_wall_time``; when it runs out there the
            result is ``timeout``, its reason saying how long the seed and each copy took, and the
            full solve is not started.
        warm: a previous answer to start from instead of ``q0`` (:mod:`refine.optimise.warm`): its
            joints moved onto the new poses are the seed, and its last problem (active set,
            joint-step rows) and multipliers are kept where they fit.
        first_options: solver options of the first strict solve alone (less those the problem's
            caller gave), such as a small initial barrier for a seed next to the answer.
        raise_on_timeout: raise :class:`TimeLimitReached` instead of returning ``timeout`` (a
            coarse copy's solve: the refinement it seeds reports the time limit).

    Raises:
        SolverError: the solver itself failed (not an infeasibility): the message names its status.
    """
    timings = StageTimes()
    start = StageTimes.clock()
    t0 = start[0]
    deadline = t0 + time_limit_s if time_limit_s is not None else math.inf
    spent: list[tuple[int, float, float | None]] = []  # the coarse copies' solves (CoarseTimeLimit)
    # the tilt each demonstrated pose needs for the wrist centre to be in reach: a seed tilted into
    # reach (off the stretched elbow) converges where the demonstrated one cannot, and a tilt beyond
    # the cone (or cone + slack) proves the strict (or repaired) problem infeasible without a solve
    tilts, _ = reach_tilts(
        kin := problem_kinematics(problem), problem.fused, problem.tolerances, problem.axisymmetric
    )
    certain = _tilt_is_a_bound(problem)
    rotations = None
    stretched = np.zeros(problem.n_waypoints, dtype=bool)
    if tilts.max() > 0.0:
        inset, rotations = reach_tilts(
            kin, problem.fused, problem.tolerances, problem.axisymmetric, SEED_INSET_M
        )
        stretched = inset > 0.0
    multipliers = None
    seed_jacobians = None  # the TCP Jacobians at a warm seed, from its projection
    seed_poses = None  # and its TCP poses
    if warm is not None:
        for src in sources:
            carry = getattr(src, "carry_from", None)
            if carry is not None and warm.clearance is not None:
                carry(warm.clearance)
        if problem.tolerances.singularity_margin > 0:  # the seed's measures start from these
            seed_jacobians = np.empty((problem.n_waypoints, 6, problem.dof))
        seed_poses = np.empty((problem.n_waypoints, 4, 4))
        q0 = warm_seed(problem, warm, seed_jacobians, seed_poses)
        final = None
        if warm.problem is not None and warm.reusable:
            final = reuse_final(warm.problem, problem, problem.fused, problem.tolerances)
        elif warm.problem is not None and warm.multipliers is not None:
            final = rebuilt_like(warm.problem, problem)
        if final is not None and final.active.linear_rows:
            final = _refreshed_rows(final, sources, q0)
        if final is not None:
            problem, multipliers = final, warm.multipliers
    cone = problem.tolerances.orientation_deg
    slack_max = repair_max_slack_deg if repair_max_slack_deg is not None else 0.0
    beyond = certain & (tilts > cone + slack_max + TILT_TOLERANCE_DEG)
    skip_strict = (
        "not run (the demonstrated orientation is out of reach beyond the cone)"
        if (certain & (tilts > cone + TILT_TOLERANCE_DEG)).any()
        else ""
    )
    # a redundant arm's seed comes from a coarse refinement (coarse_seed), which needs the chained
    # IK at its waypoints alone; the whole chain is the fallback where that seed fails
    coarse_at = coarse_waypoints(problem) if q0 is None and rotations is None else None
    coarse_iterations, smooth = 0, None
    give_up = turn_over_step(problem) if q0 is None and max_branches > 1 else None
    if coarse_at is not None and not skip_strict and not beyond.any():
        chain_at, chain_errors = chained_seed(problem, home, at=coarse_at, give_up=give_up)
        if float(chain_errors.max()) <= CONVERGED:  # else as before: the whole chain, then coarse_seed
            try:
                smooth, coarse_iterations = _coarse_seed_at(problem, coarse_at, chain_at, deadline, spent)
            except CoarseTimeLimit:  # the seed of the answer: the coarse chain along the arc length
                s = problem.fused.s
                q_chain = np.column_stack([np.interp(s, s[coarse_at], c) for c in chain_at.T])
                add_time(timings, "seed", start)
                return timed_out(problem, q_chain, time_limit_s, timings, _coarse_time(spent, t0))
            coarse_at = None  # tried: not again from the whole chain
    if smooth is not None:
        q_seed = smooth
    elif q0 is not None:
        q_seed = np.asarray(q0, dtype=float)
    elif give_up is None:
        q_seed = initial_guess(problem, home, rotations)
    else:  # a chain that turns the arm over is abandoned there
        q_seed = whole_chain(problem, kin, home, rotations, give_up)
    unreachable = out_of_reach(problem, q_seed, home, seed_poses if q_seed is q0 else None)
    add_time(timings, "seed", start)
    if not unreachable and beyond.any():
        t1, c1 = StageTimes.clock()
        findings = findings_of(problem, sources, "infeasible", q_seed, beyond)
        add_time(timings, "diagnose", (t1, c1))
        reason = (
            f"no repair within {slack_max:g} deg of extra slack: "
            if slack_max > 0
            else "out of reach as demonstrated: "
        ) + "; ".join(f.describe() for f in findings)
        log.info("refinement infeasible before solving: %s", reason)
        return unsolved(
            problem, q_seed, reason, "not run (orientation out of reach beyond the slack)", timings, findings
        )
    if unreachable:
        check = check_path(kin, q_seed, problem.fused, problem.tolerances, problem.axisymmetric)
        t0, c0 = StageTimes.clock()
        mask = np.zeros(problem.n_waypoints, dtype=bool)
        for v in unreachable:
            mask[v.index_start : v.index_end + 1] = True
        findings = findings_of(problem, sources, "infeasible", q_seed, mask)
        add_time(timings, "diagnose", (t0, c0))
        reason = "; ".join([v.describe() for v in unreachable] + [f.describe() for f in findings])
        log.info("refinement infeasible before solving: %s", reason)
        return Refinement(
            "infeasible",
            reason,
            q_seed,
            q_seed,
            replace(check, violations=tuple(unreachable) + check.violations),
            "not run (out of reach)",
            0,
            0,
            timings_s=timings,
            diagnosis=findings,
        )

    if q0 is None and smooth is None and max_branches > 1:
        # a chain that turns the arm over in one step (the points all in reach): not solved as it is
        seeding = StageTimes.clock()
        q_seed = steady_branch(problem, kin, q_seed, home, rotations, BRANCH_CANDIDATES * (max_branches - 1))
        add_time(timings, "seed", seeding)
    first_options = dict(first_options or {})
    if coarse_at is not None and not skip_strict:  # a chained seed the coarse refinement did not see
        seeding = StageTimes.clock()
        try:
            smooth, coarse_iterations = coarse_seed(problem, q_seed, deadline, spent)
        except CoarseTimeLimit:
            add_time(timings, "seed", seeding)
            return timed_out(problem, q_seed, time_limit_s, timings, _coarse_time(spent, t0))
        q_seed = q_seed if smooth is None else smooth
        add_time(timings, "seed", seeding)
    if smooth is not None and problem.tool_in_world is not None and problem.solver_name == "ipopt":
        first_options["ipopt.mu_init"] = COARSE_SEEDED_MU_INIT

    repairing = repair_max_slack_deg is not None and repair_max_slack_deg > 0

    def attempt_from(seed: Array, skip: str = skip_strict, options: dict | None = None) -> Refinement:
        jacobians = seed_jacobians if seed is q_seed else None
        return solve_with_repair(
            problem,
            seed,
            sources,
            repair_max_slack_deg,
            max_rounds,
            timings,
            deadline,
            skip,
            stretched,
            multipliers,
            options,
            jacobians,
        )

    try:
        attempt = attempt_from(q_seed, options=first_options)
    except TimeLimitReached:
        if raise_on_timeout:
            raise
        return timed_out(problem, q_seed, time_limit_s, timings)
    if attempt.status == "infeasible" and q0 is None and max_branches > 1 and time.perf_counter() < deadline:
        # the first IK branch may be the wrong one: try the first waypoint's other branches
        start = StageTimes.clock()
        lower, upper = problem_bounds(problem)
        # chained towards the same poses as the first seed (tilted into reach), more than will be
        # tried, and tried best chain first
        targets = problem_targets(problem)
        if rotations is not None:
            targets[:, :3, :3] = rotations
        chains = alternative_seeds(
            kin,
            targets,
            lower,
            upper,
            start_candidates(lower, upper, home),
            skip=q_seed,
            count=BRANCH_CANDIDATES * (max_branches - 1),
        )
        others = rank_chains(kin, targets, lower, upper, chains)[: max_branches - 1]
        add_time(timings, "seed", start)
        # the seeds whose elastic repair failed (branch, joints): the first's, with repair on
        failed = [(1, q_seed)] if repairing else []
        skipped: list[tuple[int, int]] = []  # (branch, the failed branch with its seed)
        for k, q_other in enumerate(others, start=2):
            same = next((j for j, q in failed if np.abs(q_other - q).max() <= SAME_SEED_RAD), None)
            if same is not None:
                log.info("IK branch %d: the seed of branch %d, whose repair failed; not solved", k, same)
                skipped.append((k, same))
                continue
            try:
                # the elastic problem alone: its answer without slack is the strict one, and the
                # strict solve already failed on the first branch
                other = attempt_from(q_other, skip_strict or (ELASTIC_ONLY if repairing else ""))
            except TimeLimitReached:
                limit = f"time limit {time_limit_s:g} s" if time_limit_s is not None else "IPOPT's wall-time limit"
                note = f"IK branches after the first {k - 1} not tried: {limit} reached"
                skips = f" ({_skips(skipped)})" if skipped else ""
                attempt = replace(attempt, reason=f"{attempt.reason} ({note}){skips}")
                break
            log.info("IK branch %d: %s", k, other.status)
            if other.status != "infeasible":
                attempt = replace(other, iterations=attempt.iterations + other.iterations)
                break
            if repairing:
                failed.append((k, q_other))
        else:
            tried = f"{1 + len(others)} IK branch(es) tried" + (f", {_skips(skipped)}" if skipped else "")
            attempt = replace(attempt, reason=f"{attempt.reason} ({tried})" if others else attempt.reason)
    attempt = replace(attempt, iterations=attempt.iterations + coarse_iterations)
    if (
        attempt.status == "infeasible"
        and problem.solver_name == "fatrop"
        and FATROP_FAILED in attempt.solver_status
    ):
        attempt = replace(attempt, reason=f"{attempt.reason} ({FATROP_HINT})")
    log.info(
        "refinement %s after %d solver iterations in %d rounds",
        attempt.status,
        attempt.iterations,
        attempt.outer_iterations,
    )
    return attempt


def _skips(skipped: list[tuple[int, int]]) -> str:
    """The IK branches not solved, their seed that of a branch whose repair failed, for the reason; or ""."""
    which = "; ".join(f"branch {k} has the same seed as branch {j}" for k, j in skipped)
    return f"{len(skipped)} skipped: {which}" if skipped else ""


def _coarse_time(spent: list[tuple[int, float, float | None]], t0: float) -> str:
    """Where the time went when it ran out in the coarse copies, for the reason (wall time [s])."""
    parts = [f"{spent[0][1] - t0:.3g} s seeding" if spent else "seeding"]
    for n, begun, ended in spent:
        took = "not started" if ended is None else f"{ended - begun:.3g} s"
        parts.append(f"the {n}-waypoint coarse copy {took}")
    return f"in the coarse copies that seed the full solve, which was not started (wall time: {', '.join(parts)})"


def _refreshed_rows(
    problem: RefinementNLP, sources: tuple[ConstraintSource, ...], q: Array
) -> RefinementNLP | None:
    """``problem`` with its linear rows' bounds taken again at joints ``q`` (N, n), or None.

    The rows were linearised against the cell as it was; each source that made them
    (``refresh_rows``) measures their pairs again at ``q`` and keeps their gradients. None when a
    row has no source to refresh it (the problem is then rebuilt by the rounds as usual).
    """
    rows = problem.active.linear_rows
    for src in sources:
        refresh = getattr(src, "refresh_rows", None)
        if refresh is not None:
            rows = refresh(rows, q)
    if rows is problem.active.linear_rows or len(rows) != len(problem.active.linear_rows):
        return None
    head = len(problem.lbg) - len(rows)
    lbg = np.concatenate([problem.lbg[:head], [r.lower for r in rows]])
    return replace(problem, lbg=lbg, active=replace(problem.active, linear_rows=rows))


def _tilt_is_a_bound(problem: RefinementNLP) -> bool:
    """Whether the reach tilt bounds the orientation deviation from below for this tool.

    Always for a tool whose whole orientation counts; for an axisymmetric tool only when the wrist
    centre lies on the tool axis (the free spin about the axis then cannot move it).
    """
    if not problem.axisymmetric:
        return True
    from refine.optimise.reach import reach_model

    reach = reach_model(problem.robot, math.radians(problem.tolerances.joint_margin_deg))
    v = (np.linalg.inv(problem.tcp_in_flange) @ np.append(reach.point_in_flange, 1.0))[:3]
    return bool(np.linalg.norm(np.cross(v, [0.0, 0.0, 1.0])) <= 1e-6 * max(np.linalg.norm(v), 1e-9))


def coarse_seed(
    problem: RefinementNLP,
    q_seed: Array,
    deadline: float = math.inf,
    spent: list[tuple[int, float, float | None]] | None = None,
) -> tuple[Array | None, int]:
    """A redundant arm's seed from the refinement of a coarse copy of the path, and the iterations it took.

    Returns the seed (N, n) [rad], None where there is none, and the solver iterations spent on the
    coarse copies (0 when none was solved), which count in the refinement's iterations.

    The chained IK leaves a redundant arm's elbow where the mid-range pull puts it, waypoint by
    waypoint, while the refined path puts it where the whole path's joint motion is least: IPOPT then
    needs 150-300 iterations to move it there (LBR iiwa without a mid-range cost). The same refinement
    over evenly spaced waypoints (:func:`refine.optimise.coarse.coarse_waypoints`: every 40th, at least
    16; seeded with the chained joints there, which the refinement chains at those waypoints alone;
    posed by :func:`refine.optimise.coarse.coarse_copy`: the joint-step bound scaled by the spacing, at
    most 360 deg, no clearance rows) finds that elbow cheaply. Its joints, interpolated along the arc
    length and projected onto every waypoint's exact pose by least-squares IK without null-space drift,
    start the full solve next to its answer. A held part on a long path
    (:func:`refine.optimise.coarse.ladder_waypoints`) climbs a ladder: that answer, projected onto a
    finer copy's waypoints, seeds the finer copy's solve (``ipopt.mu_init``
    :data:`COARSE_SEEDED_MU_INIT`), and the finer answer seeds the full solve; where the finer copy is
    not ``ok`` or its seed or answer misses a pose, the first copy's answer seeds it as without the
    ladder. None for a non-redundant arm, a path shorter than
    :data:`~refine.optimise.coarse.COARSE_SEED_MIN_PATH`, a coarse refinement that is not ``ok`` or a
    projection that misses a pose.

    The copies are solved by :func:`_copy_answer` before ``deadline`` (:func:`time.perf_counter`
    [s]), each noted in ``spent``; raises :class:`CoarseTimeLimit` when it passes there.
    """
    idx = coarse_waypoints(problem)
    if idx is None:
        return None, 0
    spent = [] if spent is None else spent
    return _coarse_seed_at(problem, idx, np.asarray(q_seed, dtype=float)[idx], deadline, spent)


def _copy_answer(
    problem: RefinementNLP,
    idx: Array,
    seed: Array,
    deadline: float,
    spent: list[tuple[int, float, float | None]],
    first_options: dict | None = None,
) -> Refinement:
    """The refinement of ``problem``'s coarse copy at the waypoints ``idx`` from ``seed`` (len(idx), n) [rad].

    Before ``deadline`` (:func:`time.perf_counter` [s]; inf for none): the copy's IPOPT gets the
    time then left as ``max_wall_time`` and its refinement the time left after the build as
    ``time_limit_s``; the copy is noted in ``spent`` with its start and end.

    Raises:
        CoarseTimeLimit: the deadline (or the call's) passed before the copy's solve or during it.
    """
    begun = time.perf_counter()
    if begun >= deadline or out_of_time():
        spent.append((len(idx), begun, None))
        raise CoarseTimeLimit(spent)
    limited = math.isfinite(deadline)
    copy = coarse_copy(problem, idx, deadline - begun if limited else None)
    try:
        answer = solve_refinement(
            copy,
            seed,
            time_limit_s=max(deadline - time.perf_counter(), 0.0) if limited else None,
            first_options=first_options,
            raise_on_timeout=True,
        )
    except TimeLimitReached as e:
        spent.append((len(idx), begun, time.perf_counter()))
        raise CoarseTimeLimit(spent) from e
    spent.append((len(idx), begun, time.perf_counter()))
    return answer


def _coarse_seed_at(
    problem: RefinementNLP,
    idx: Array,
    q_coarse: Array,
    deadline: float,
    spent: list[tuple[int, float, float | None]],
) -> tuple[Array | None, int]:
    """:func:`coarse_seed` from the joints ``q_coarse`` [rad] at the coarse waypoints ``idx``."""
    answer = _copy_answer(problem, idx, q_coarse, deadline, spent)
    if answer.status != "ok":
        log.info(
            "coarse seed: the %d-waypoint refinement is %s; the chained IK seed stays",
            len(idx),
            answer.status,
        )
        return None, answer.iterations
    log.info("coarse seed: %d waypoints refined in %d solver iterations", len(idx), answer.iterations)
    iterations = answer.iterations
    finer = ladder_waypoints(problem)
    if finer is not None:
        q_finer, iterations = _ladder_rung(problem, idx, answer.q, finer, iterations, deadline, spent)
        if q_finer is not None:
            q, missed = projected(problem, finer, q_finer)
            if not missed:
                return q, iterations
            log.info(
                "coarse ladder: the projection misses %d poses; the %d-waypoint answer seeds",
                missed,
                len(idx),
            )
    q, missed = projected(problem, idx, answer.q)
    if missed:
        log.info("coarse seed: the projection misses %d poses; the chained IK seed stays", missed)
        return None, iterations
    return q, iterations


def _ladder_rung(
    problem: RefinementNLP,
    idx: Array,
    q_coarse: Array,
    finer: Array,
    iterations: int,
    deadline: float,
    spent: list[tuple[int, float, float | None]],
) -> tuple[Array | None, int]:
    """The answer (len(finer), n) [rad] of the copy at ``finer``, seeded from ``q_coarse`` at ``idx``.

    Also returns ``iterations`` with the finer copy's added. None (the coarser answer seeds the full
    solve) when the seed misses a pose, the finer copy's answer is not ``ok`` or its solver fails
    to run (:class:`refine.errors.SolverError`: the full solve meets it again if it is the problem's).
    Solved by :func:`_copy_answer` before ``deadline``.
    """
    seed, missed = projected(problem, idx, q_coarse, finer)
    if missed:
        log.info("coarse ladder: the %d-waypoint seed misses %d poses; not climbed", len(finer), missed)
        return None, iterations
    try:
        answer = _copy_answer(
            problem, finer, seed, deadline, spent, first_options={"ipopt.mu_init": COARSE_SEEDED_MU_INIT}
        )
    except SolverError as e:  # no answer of the finer copy: the ladder is a seed only, not climbed
        log.info("coarse ladder: the %d-waypoint refinement failed (%s); not climbed", len(finer), e)
        return None, iterations
    iterations += answer.iterations
    if answer.status != "ok":
        log.info("coarse ladder: the %d-waypoint refinement is %s; not climbed", len(finer), answer.status)
        return None, iterations
    log.info("coarse ladder: %d waypoints refined in %d solver iterations", len(finer), answer.iterations)
    return answer.q, iterations
